"""Tests for identification.logs (seeklog, formats): format round trips, every bad-input error, fuzzing, segmentation."""
from __future__ import annotations

import io
import json
import os
import pickle
import zipfile

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from identification.logs import formats as logs
from identification.logs import LogError, Seek, SeekLog, read_log, segment_seeks, settle_windows, write_log

FS = 10_000.0
FUZZ = settings(max_examples=120, deadline=None, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def make_log(n=200, seed=0, **kw):
    rng = np.random.default_rng(seed)
    target = np.where(np.arange(n) < n // 2, 0.0, 1234.0)
    kw.setdefault("metadata", {"drive": "A1-07", "note": "has: colons, commas"})
    kw.setdefault("extra", {"u_ff_a": rng.normal(size=n), "temp_c": np.full(n, 41.5)})
    return SeekLog.from_arrays(np.arange(n) / FS, rng.normal(size=n) * 0.3, target + rng.normal(size=n),
                               target, FS, track_pitch_nm=kw.pop("track_pitch_nm", 73.25), **kw)


def assert_same(a: SeekLog, b: SeekLog):
    for c in logs.COLUMNS:
        np.testing.assert_array_equal(getattr(a, c), getattr(b, c))
    assert (a.sample_rate_hz, a.track_pitch_nm, a.metadata) == (b.sample_rate_hz, b.track_pitch_nm, b.metadata)
    assert list(a.extra) == list(b.extra)
    for k in a.extra:
        np.testing.assert_array_equal(a.extra[k], b.extra[k])


def csv_text(n=100, rate=FS, cols=None, meta=None, t=None):
    """A valid CSV (unless changed by the arguments) with a seek at n // 2."""
    t = np.arange(n) / FS if t is None else t
    data = {"time_s": t, "current_a": np.sin(np.arange(n)), "position_track": np.linspace(0, 5, n),
            "target_track": np.where(np.arange(n) < n // 2, 0.0, 5.0)}
    cols = list(data) if cols is None else cols
    head = {"sample_rate_hz": rate} if meta is None else meta
    lines = [f"# {k}: {v}" for k, v in head.items()] + [",".join(cols)]
    lines += [",".join(repr(float(data[c][i])) for c in cols) for i in range(n)]
    return "\n".join(lines) + "\n"


def expect_error(path, *words):
    with pytest.raises(LogError) as info:
        read_log(path)
    msg = str(info.value)
    assert len(msg.splitlines()) == 1, msg
    assert path.name in msg, msg
    for w in words:
        assert w in msg, msg
    return msg


# ------------------------------------------------------------------------------------ round trips
@pytest.mark.parametrize("ext", [".csv", ".npz", ".mat"])
def test_round_trip_exact(tmp_path, ext):
    log = make_log()
    log.extra["with_nan"] = np.where(np.arange(log.n) % 7 == 0, np.nan, 1 / 3)
    path = tmp_path / f"run{ext}"
    write_log(log, path)
    back = read_log(path)
    assert back.source == str(path)
    assert_same(log, back)
    np.testing.assert_array_equal(back.extra["with_nan"], log.extra["with_nan"])  # NaN == NaN here
    assert back.n == 200 and back.dt == 1 / FS
    np.testing.assert_array_equal(back.pes, log.position_track - log.target_track)
    assert os.listdir(tmp_path) == [path.name]  # no temp files left


@pytest.mark.parametrize("ext", [".csv", ".npz", ".mat"])
def test_round_trip_without_pitch_or_extras(tmp_path, ext):
    log = make_log(track_pitch_nm=None, metadata={}, extra={})
    write_log(log, tmp_path / f"a{ext}")
    back = read_log(tmp_path / f"a{ext}")
    assert_same(log, back)
    assert back.track_pitch_nm is None and back.extra == {} and back.metadata == {}


def test_csv_layout(tmp_path):
    write_log(make_log(), tmp_path / "x.csv")
    lines = (tmp_path / "x.csv").read_text().splitlines()
    assert lines[:3] == ["# seekopt-log: 1", "# sample_rate_hz: 10000.0", "# track_pitch_nm: 73.25"]
    assert lines[5] == "time_s,current_a,position_track,target_track,u_ff_a,temp_c"


def test_column_order_independent(tmp_path):
    cols = ["target_track", "current_a", "time_s", "position_track"]
    (tmp_path / "a.csv").write_text(csv_text())
    (tmp_path / "b.csv").write_text(csv_text(cols=cols, meta={"sample_rate_hz": FS, "station": " 4 "}))
    a, b = read_log(tmp_path / "a.csv"), read_log(tmp_path / "b.csv")
    assert_same(a, SeekLog.from_arrays(b.time_s, b.current_a, b.position_track, b.target_track, FS))
    assert b.metadata == {"station": "4"}
    log = make_log()
    arrays = {c: getattr(log, c) for c in reversed(logs.COLUMNS)}
    np.savez(tmp_path / "c.npz", **arrays, metadata=json.dumps({"sample_rate_hz": FS}))
    np.testing.assert_array_equal(read_log(tmp_path / "c.npz").position_track, log.position_track)


def test_foreign_variants_accepted(tmp_path):
    """MATLAB struct metadata; top-level scalar sample rate in npz; numeric strings; comments."""
    from scipy.io import savemat
    log = make_log()
    cols = {c: getattr(log, c) for c in logs.COLUMNS}
    savemat(tmp_path / "s.mat", {**cols, "metadata": {"sample_rate_hz": FS, "rig": "B"}})
    back = read_log(tmp_path / "s.mat")
    assert back.sample_rate_hz == FS and back.metadata == {"rig": "B"}
    np.savez(tmp_path / "s.npz", sample_rate_hz=FS, **cols)
    assert read_log(tmp_path / "s.npz").sample_rate_hz == FS
    text = "# plain comment\n\n" + csv_text().replace("\n", "\n\n", 3) + "# trailing comment\n"
    assert read_log(_write(tmp_path, "c.csv", text)).n == 100


def test_slice_and_from_arrays():
    log = make_log()
    part = log.slice(10, 50)
    assert part.n == 40 and part.time_s[0] == log.time_s[10] and part.extra["u_ff_a"].shape == (40,)
    part.current_a[:] = 0
    assert log.current_a[10] != 0  # slice copies
    auto = SeekLog.from_arrays(None, log.current_a, log.position_track, log.target_track, FS)
    np.testing.assert_allclose(auto.time_s, log.time_s)
    with pytest.raises(LogError, match="<arrays>: .*current_a is NaN"):
        SeekLog.from_arrays(None, np.full(100, np.nan), np.zeros(100), np.arange(100.0), FS)
    with pytest.raises(LogError, match="invalid metadata"):
        make_log(metadata={"sample_rate_hz": 1})
    err = pickle.loads(pickle.dumps(LogError("f.csv", "row 2: bad")))
    assert str(err) == "f.csv: row 2: bad" and err.file == "f.csv" and err.problem == "row 2: bad"


# -------------------------------------------------------------------------------------- atomicity
def test_write_is_atomic(tmp_path, monkeypatch):
    path = tmp_path / "keep.npz"
    write_log(make_log(seed=1), path)
    before = path.read_bytes()

    def boom(fd):
        raise OSError("disk full")
    monkeypatch.setattr(logs.os, "fsync", boom)
    with pytest.raises(OSError, match="disk full"):
        write_log(make_log(seed=2), path)
    monkeypatch.undo()
    bad = make_log(seed=3)
    bad.current_a[5] = np.nan
    with pytest.raises(LogError, match="keep.npz: row 6: current_a is NaN"):
        write_log(bad, path)
    assert path.read_bytes() == before
    assert os.listdir(tmp_path) == ["keep.npz"]


def test_write_errors(tmp_path):
    with pytest.raises(LogError, match=r"x\.txt: unknown extension"):
        write_log(make_log(), tmp_path / "x.txt")
    log = make_log(extra={"bad name": np.zeros(200)})
    write_log(log, tmp_path / "ok.csv")
    assert "bad name" in read_log(tmp_path / "ok.csv").extra
    with pytest.raises(LogError, match="MATLAB"):
        write_log(log, tmp_path / "x.mat")
    assert sorted(os.listdir(tmp_path)) == ["ok.csv"]


# ------------------------------------------------------------------------------------- bad inputs
def _write(tmp_path, name, text):
    path = tmp_path / name
    (path.write_bytes if isinstance(text, bytes) else path.write_text)(text)
    return path


def test_missing_column(tmp_path):
    path = _write(tmp_path, "run1.csv", csv_text(cols=["time_s", "current_a", "position_track"]))
    expect_error(path, "missing column", "target_track")


def test_missing_sample_rate(tmp_path):
    expect_error(_write(tmp_path, "r.csv", csv_text(meta={"track_pitch_nm": 80})), "missing", "sample_rate_hz")
    log = make_log()
    np.savez(tmp_path / "r.npz", **{c: getattr(log, c) for c in logs.COLUMNS})
    expect_error(tmp_path / "r.npz", "missing", "sample_rate_hz")


@pytest.mark.parametrize("bad, word", [("nan", "NaN"), ("inf", "+inf"), ("-inf", "-inf")])
def test_nonfinite_value(tmp_path, bad, word):
    lines = csv_text().splitlines()
    cells = lines[2 + 3].split(",")  # 1 metadata line + header; data row 4
    cells[1] = bad
    lines[5] = ",".join(cells)
    expect_error(_write(tmp_path, "run3.csv", "\n".join(lines)), "row 4: current_a is " + word)


def test_nan_in_npz_reports_row_and_column(tmp_path):
    log = make_log()
    pos = log.position_track.copy()
    pos[[2, 50]] = np.nan
    np.savez(tmp_path / "p.npz", **{c: getattr(log, c) for c in logs.COLUMNS[:2]}, position_track=pos,
             target_track=log.target_track, metadata=json.dumps({"sample_rate_hz": FS}))
    expect_error(tmp_path / "p.npz", "row 3", "position_track", "NaN")


def test_non_uniform_time(tmp_path):
    t = np.arange(100) / FS
    t[40:] += 0.05 / FS  # one 5 % longer step
    expect_error(_write(tmp_path, "j.csv", csv_text(t=t)), "non-uniform", "row 41")
    t = (np.arange(100) + 0.004 * np.sin(np.arange(100))) / FS  # jitter < 1 % of dt is fine
    assert read_log(_write(tmp_path, "ok.csv", csv_text(t=t))).n == 100


@pytest.mark.parametrize("i, word", [(30, "repeated"), (31, "decreasing")])
def test_time_not_increasing(tmp_path, i, word):
    t = np.arange(100) / FS
    t[30] = t[29] if word == "repeated" else t[30]
    t[31] = t[29] if word == "decreasing" else t[31]
    expect_error(_write(tmp_path, "t.csv", csv_text(t=t)), word, f"row {i + 1}", "time_s")


def test_rate_disagrees(tmp_path):
    expect_error(_write(tmp_path, "f.csv", csv_text(rate=FS * 1.002)), "sample_rate_hz", "disagrees")
    assert read_log(_write(tmp_path, "g.csv", csv_text(rate=FS * 1.0009))).sample_rate_hz == FS * 1.0009


def test_bad_metadata_values(tmp_path):
    expect_error(_write(tmp_path, "a.csv", csv_text(meta={"sample_rate_hz": "10 kHz"})), "sample_rate_hz", "not a number")
    expect_error(_write(tmp_path, "b.csv", csv_text(meta={"sample_rate_hz": -5})), "positive")
    expect_error(_write(tmp_path, "c.csv", csv_text(meta={"sample_rate_hz": FS, "track_pitch_nm": "x"})), "track_pitch_nm")
    expect_error(_write(tmp_path, "d.csv", csv_text(meta={"seekopt-log": 2, "sample_rate_hz": FS})), "version")
    expect_error(_write(tmp_path, "e.csv", "# sample_rate_hz: 1\n" + csv_text()), "duplicate metadata")


def test_too_short(tmp_path):
    expect_error(_write(tmp_path, "s.csv", csv_text(n=63)), "too short", "63")
    expect_error(_write(tmp_path, "h.csv", csv_text(n=0)), "too short", "0 samples")
    assert read_log(_write(tmp_path, "ok.csv", csv_text(n=64))).n == 64


def test_no_seek(tmp_path):
    text = csv_text().replace(",5.0\n", ",0.0\n")
    expect_error(_write(tmp_path, "still.csv", text), "no seek")


def test_non_numeric_cell(tmp_path):
    lines = csv_text().splitlines()
    lines[4] = lines[4].replace(",", ",abc", 1)
    expect_error(_write(tmp_path, "n.csv", "\n".join(lines)), "row 3", "current_a", "not a number", "abc")
    lines = csv_text().splitlines()
    lines[4] = "," + lines[4].split(",", 1)[1]
    expect_error(_write(tmp_path, "m.csv", "\n".join(lines)), "row 3", "time_s is empty")


def test_ragged_rows_and_bad_header(tmp_path):
    lines = csv_text().splitlines()
    lines[10] += ",1.0"
    expect_error(_write(tmp_path, "r.csv", "\n".join(lines)), "row 9", "expected 4 fields, got 5")
    expect_error(_write(tmp_path, "d.csv", csv_text().replace("target_track\n", "target_track,time_s\n")),
                 "duplicate column")
    expect_error(_write(tmp_path, "q.csv", csv_text().replace("time_s,", '"time_s,', 1)), "CSV")


@pytest.mark.parametrize("name, content, word", [
    ("empty.csv", b"", "empty file"),
    ("blank.npz", b"  \n\n", "empty file"),
    ("comments.csv", b"# sample_rate_hz: 10\n# only comments\n", "no header"),
    ("binary.csv", bytes(range(256)) * 4, "UTF-8"),
    ("garbage.npz", b"this is not a zip archive" * 10, "unreadable .npz"),
    ("garbage.mat", os.urandom(300), "unreadable .mat"),
    ("text.mat", csv_text().encode(), "unreadable .mat"),
])
def test_unreadable_files(tmp_path, name, content, word):
    expect_error(_write(tmp_path, name, content), word)


def test_missing_file_and_unknown_extension(tmp_path):
    expect_error(tmp_path / "nope.csv", "cannot read")
    expect_error(_write(tmp_path, "run.txt", csv_text()), "unknown extension", ".txt")
    expect_error(_write(tmp_path, "noext", csv_text()), "unknown extension")


def test_bad_npz_and_mat_contents(tmp_path):
    log = make_log()
    cols = {c: getattr(log, c) for c in logs.COLUMNS}
    np.savez(tmp_path / "j.npz", **cols, metadata="{not json")
    expect_error(tmp_path / "j.npz", "JSON")
    np.savez(tmp_path / "k.npz", **cols, metadata=np.arange(3))
    expect_error(tmp_path / "k.npz", "metadata")
    np.savez(tmp_path / "s.npz", **{**cols, "current_a": np.array(["a"] * 200)}, metadata='{"sample_rate_hz": 1e4}')
    expect_error(tmp_path / "s.npz", "current_a", "not numeric")
    np.savez(tmp_path / "l.npz", **{**cols, "current_a": cols["current_a"][:-1]}, metadata='{"sample_rate_hz": 1e4}')
    expect_error(tmp_path / "l.npz", "current_a", "199 values")
    np.savez(tmp_path / "o.npz", **cols, metadata='{"sample_rate_hz": 1%s}' % ("0" * 400))
    expect_error(tmp_path / "o.npz", "sample_rate_hz", "not a number")
    np.savez(tmp_path / "i.npz", **cols, metadata='{"sample_rate_hz": 1e999}')
    expect_error(tmp_path / "i.npz", "sample_rate_hz", "finite")
    np.save(tmp_path / "a.npy", np.arange(5))
    os.rename(tmp_path / "a.npy", tmp_path / "a.npz")
    expect_error(tmp_path / "a.npz", "unreadable .npz")
    from scipy.io import savemat
    savemat(tmp_path / "m.mat", {**cols, "metadata": '{"sample_rate_hz": 1e4}', "pos2d": np.zeros((200, 2))})
    expect_error(tmp_path / "m.mat", "pos2d", "1-D")


def test_corrupt_mat_never_reaches_scipy_crash(tmp_path):
    """Corruptions that segfault scipy's compiled loadmat (seen while fuzzing) must become LogError."""
    from scipy.io import savemat
    base = logs._mat_bytes("x", make_log())
    assert base[184] == 9 and base[145] == 0  # data-element type of the 1st variable; its flags byte
    expect_error(_write(tmp_path, "type.mat", base[:184] + bytes([125]) + base[185:]), "corrupt element")
    expect_error(_write(tmp_path, "cplx.mat", base[:145] + bytes([8]) + base[146:]), "complex")
    cols = {c: getattr(make_log(), c) for c in logs.COLUMNS}
    savemat(tmp_path / "v4.mat", cols, format="4")
    expect_error(tmp_path / "v4.mat", "v4")
    savemat(tmp_path / "cell.mat", {**cols, "c": np.array([[1, "a"]], dtype=object)})
    expect_error(tmp_path / "cell.mat", "unsupported MATLAB class")
    for compress in (False, True):  # MATLAB-style compressed files with struct metadata are fine
        savemat(tmp_path / "ok.mat", {**cols, "metadata": {"sample_rate_hz": FS}, "flag": np.arange(200) % 2 == 0},
                do_compression=compress)
        np.testing.assert_array_equal(read_log(tmp_path / "ok.mat").extra["flag"], np.arange(200) % 2 == 0)


# ------------------------------------------------------------------------------------------ fuzzing
def check_outcome(path):
    try:
        log = read_log(path)
    except LogError as exc:
        msg = str(exc)
        assert len(msg.splitlines()) == 1 and path.name in msg, msg
    else:
        assert isinstance(log, SeekLog) and log.n >= logs.MIN_SAMPLES


@FUZZ
@given(data=st.binary(max_size=2000), ext=st.sampled_from([".csv", ".npz", ".mat"]))
def test_fuzz_random_bytes(tmp_path, data, ext):
    path = tmp_path / f"fuzz{ext}"
    path.write_bytes(data)
    check_outcome(path)


@FUZZ
@given(text=st.text(max_size=2000))
def test_fuzz_random_text(tmp_path, text):
    path = tmp_path / "fuzz.csv"
    path.write_bytes(text.encode("utf-8", "surrogatepass"))
    check_outcome(path)


_BASE_CSV = csv_text(n=70, meta={"seekopt-log": 1, "sample_rate_hz": FS, "track_pitch_nm": 80})
_PIECES = st.sampled_from(["nan", "inf", ",", "\n", "#", ":", '"', "\r", "\x00", "1e999", "-", " ", "",
                           "time_s", "sample_rate_hz", "0.0001", "1,2,3,4", "\u2028", "# sample_rate_hz: 7"])
_EDIT = st.tuples(st.sampled_from(["insert", "delete", "replace", "truncate", "dup_line", "drop_line"]),
                  st.integers(0, len(_BASE_CSV)), st.integers(0, 40), st.one_of(_PIECES, st.text(max_size=5)))


def mangle(text, edits):
    for op, pos, k, piece in edits:
        pos = min(pos, len(text))
        if op == "insert":
            text = text[:pos] + piece + text[pos:]
        elif op == "delete":
            text = text[:pos] + text[pos + k:]
        elif op == "replace":
            text = text[:pos] + piece + text[pos + len(piece):]
        elif op == "truncate":
            text = text[:pos]
        else:
            lines = text.split("\n")
            i = min(k, len(lines) - 1)
            lines[i:i + 1] = [lines[i]] * (2 if op == "dup_line" else 0)
            text = "\n".join(lines)
    return text


@FUZZ
@given(edits=st.lists(_EDIT, min_size=1, max_size=6))
def test_fuzz_mangled_csv(tmp_path, edits):
    path = tmp_path / "mangled.csv"
    path.write_bytes(mangle(_BASE_CSV, edits).encode("utf-8", "surrogatepass"))
    check_outcome(path)


_BINARIES = {".npz": logs._npz_bytes("x", make_log(n=70)), ".mat": logs._mat_bytes("x", make_log(n=70))}


@FUZZ
@given(ext=st.sampled_from([".npz", ".mat"]),
       flips=st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)), max_size=8),
       cut=st.one_of(st.none(), st.integers(0, 10**6)))
def test_fuzz_mangled_binary(tmp_path, ext, flips, cut):
    data = bytearray(_BINARIES[ext])
    for pos, byte in flips:
        data[pos % len(data)] = byte
    path = tmp_path / f"mangled{ext}"
    path.write_bytes(bytes(data[:cut] if cut is not None else data))
    check_outcome(path)


def test_fixture_binaries_are_valid(tmp_path):
    for ext, data in _BINARIES.items():
        assert read_log(_write(tmp_path, "v" + ext, data)).n == 70
    assert zipfile.is_zipfile(io.BytesIO(_BINARIES[".npz"]))


# ------------------------------------------------------------------------------------- segmentation
def seg_log(n=300):
    target = np.zeros(n)
    target[50:150], target[150:] = 100.0, 40.0
    pes = np.zeros(n)
    pes[50:80] = -5.0       # seek 1 moving in
    pes[80] = 0.1           # exactly on the band edge: in band
    pes[81] = 0.2           # last out-of-band sample -> settles at 82
    pes[150:295] = 3.0      # seek 2 still out of band until 295
    pes[10] = 7.0           # disturbance before the first seek is not a seek
    return SeekLog.from_arrays(None, np.zeros(n), target + pes, target, FS)


def test_segment_seeks_known_log():
    log = seg_log()
    seeks = segment_seeks(log)
    assert seeks == [Seek(50, 82, 150, 0.0, 100.0, 100.0, True), Seek(150, 300, 300, 100.0, 40.0, -60.0, False)]
    assert seeks[0].settle_samples == 32
    assert settle_windows(log, seeks) == [(82, 150)]
    assert settle_windows(log) == [(82, 150)]
    loose = segment_seeks(log, min_settle_samples=5)
    assert loose[1] == Seek(150, 295, 300, 100.0, 40.0, -60.0, True)
    assert settle_windows(log, loose) == [(82, 150), (295, 300)]
    wide = segment_seeks(log, settle_band=3.0)
    assert [s.settle for s in wide] == [80, 150]


def test_segment_seeks_edge_cases():
    log = seg_log()
    log.target_track[299] = 41.0  # a third seek in the last sample: too short to settle
    seeks = segment_seeks(log)
    assert [(s.start, s.end, s.settled) for s in seeks] == [(50, 150, True), (150, 299, False), (299, 300, False)]
    assert seeks[2].length_track == 1.0
    with pytest.raises(ValueError):
        segment_seeks(log, settle_band=0)
    with pytest.raises(ValueError):
        settle_windows(log.slice(0, 100), seeks)


def test_substep_current_columns(tmp_path):
    """A multirate drive's sub-step currents (current_sub1_a .. current_subL_a) round-trip and come
    back from input_current() as an (n, L) array; bad ones are a one-line error naming the file."""
    n = 200
    d = np.random.default_rng(5).normal(size=n)
    cur = make_log().current_a                        # current_a must be the sub-steps' mean
    sub = np.column_stack([cur + d, cur - d])
    log = make_log(extra={"current_sub1_a": sub[:, 0], "current_sub2_a": sub[:, 1]})
    np.testing.assert_array_equal(log.input_current(), sub)
    assert make_log().input_current().shape == (n,)
    for ext in (".csv", ".npz", ".mat"):
        write_log(log, tmp_path / f"m{ext}")
        np.testing.assert_array_equal(read_log(tmp_path / f"m{ext}").input_current(), sub)
    bad = sub.copy()
    bad[17, 1] = np.nan
    nan = make_log(extra={"current_sub1_a": sub[:, 0], "current_sub2_a": sub[:, 1]})
    nan.extra["current_sub2_a"] = bad[:, 1]          # from_arrays would refuse it: write it raw
    np.savez(tmp_path / "nan.npz", **{c: getattr(nan, c) for c in logs.COLUMNS}, **nan.extra,
             metadata=json.dumps({"sample_rate_hz": FS}))
    expect_error(tmp_path / "nan.npz", "row 18", "current_sub2_a")
    lines = csv_text(100).splitlines()
    h = next(i for i, line in enumerate(lines) if line.startswith("time_s"))
    lines[h:] = [lines[h] + ",current_sub1_a,current_sub3_a"] + [line + ",0.1,0.2" for line in lines[h + 1:]]
    (tmp_path / "gap.csv").write_text("\n".join(lines) + "\n")
    expect_error(tmp_path / "gap.csv", "current_sub1_a .. current_subL_a")
