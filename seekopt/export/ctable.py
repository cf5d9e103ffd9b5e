"""C99 source of the playable seek tables and of ``seekopt_seek_sample`` (the rule of
:mod:`seekopt.export.classes`, in the same integer arithmetic as :meth:`SeekSet.play`).

Writes ``<basename>.h`` and ``<basename>.c`` (default ``seekopt_seek``); the C compiles with
``-std=c99 -Wall -Wextra -Werror -pedantic`` and needs only ``<stdint.h>``.  API::

    const seekopt_seek_set_t *seekopt_seek_find(uint32_t tpi, uint16_t member);
    int32_t seekopt_seek_samples(const seekopt_seek_set_t *set, int32_t tracks);   /* -1 no set, -2 no seek */
    int seekopt_seek_sample_set(const seekopt_seek_set_t *set, int32_t tracks, uint32_t k,
                                int16_t *u_ff, int32_t *r);
    int seekopt_seek_sample(uint32_t tpi, int32_t tracks, uint32_t k, int16_t *u_ff, int32_t *r);

``seekopt_seek_sample`` (family member 0) writes sample ``k`` of the seek of ``tracks`` tracks (signed)
from the seek start: ``*u_ff`` int16 Q15 of Imax, ``*r`` int32 track relative to the seek start with
``SEEKOPT_SEEK_REF_FRAC_BITS`` fractional bits.  Returns 1 within the seek, 0 in the hold after it
(``u = 0``, ``r = tracks * 2^F``; also for ``tracks = 0``), -1 for an unknown TPI, -2 for a length outside
``1..stroke`` (outputs 0).
"""
from __future__ import annotations

from pathlib import Path

from seekopt.export.classes import SeekRule
from seekopt.export.tables import c_array

__all__ = ["write_seek_c", "C_BASENAME"]

C_BASENAME = "seekopt_seek"

_TYPES = """typedef struct {
    int32_t k_lo;      /* shortest length of the class [track] */
    int32_t k_hi;      /* longest length = the anchor design's length [track] */
    uint32_t ff_off;   /* offset in the set's feedforward pool */
    uint32_t ref_off;  /* offset in the set's reference pool */
    uint16_t ff_len;   /* feedforward samples (0 after) */
    uint16_t ref_len;  /* reference samples (k_hi * 2^F after) */
    uint16_t settle;   /* the anchor's settle [samples] (information) */
} seekopt_rest_class_t;

typedef struct {
    int32_t k_lo;      /* shortest length that coasts with this velocity step [track] */
    int32_t d_q;       /* coast velocity [track/sample], SEEKOPT_SEEK_REF_FRAC_BITS fractional bits */
    uint32_t ff_off;
    uint32_t ref_off;
    uint16_t ff_len;
    uint16_t ref_len;  /* the reference continues as the ramp ref[last] + d_q (k - ref_len + 1) */
    uint16_t settle;   /* samples from the start of the arriving step to settle */
} seekopt_coast_class_t;

typedef struct {
    uint32_t tpi;      /* track density [track/inch] */
    uint16_t member;   /* family member (zone / temperature), 0 when the sweep has none */
    int32_t stroke;    /* longest seek [track] */
    uint16_t n_rest;
    uint16_t n_coast;
    const seekopt_rest_class_t *rest;    /* ascending k_hi, contiguous from 1 */
    const seekopt_coast_class_t *coast;  /* ascending k_lo and velocity */
    const int16_t *ff;                   /* Q15 of SEEKOPT_SEEK_IMAX_A */
    const int32_t *ref;                  /* track from the seek start, 2^-F */
} seekopt_seek_set_t;
"""

_FUNCS = r"""
static int64_t div_round(int64_t a, int64_t b)   /* a / b, b > 0, half away from zero */
{
    int64_t mag = a < 0 ? -a : a;
    int64_t q = mag / b;
    if (2 * (mag - q * b) >= b) q++;
    return a < 0 ? -q : q;
}

static int64_t ff_at(const int16_t *t, uint16_t len, int64_t j)
{
    return (j >= 0 && j < (int64_t)len) ? (int64_t)t[j] : 0;
}

static int64_t ramp_at(const int32_t *t, uint16_t len, int32_t d_q, int64_t j)
{
    if (j < 0) return 0;
    if (j < (int64_t)len) return (int64_t)t[j];
    return (len ? (int64_t)t[len - 1] : 0) + (int64_t)d_q * (j - (int64_t)len + 1);
}

static int64_t coast_m(int32_t k, int32_t d_q)   /* ceil(k 2^F / d_q) */
{
    int64_t num = (int64_t)k * ((int64_t)1 << SEEKOPT_SEEK_REF_FRAC_BITS);
    return (num + d_q - 1) / d_q;
}

/* 1: rest class *idx, 2: coast class *idx (with its m), 0: no seek of k tracks */
static int pick(const seekopt_seek_set_t *s, int32_t k, uint16_t *idx, int64_t *m)
{
    uint16_t i;
    int64_t best = -1;
    if (k < 1 || k > s->stroke) return 0;
    if (s->n_rest && k <= s->rest[s->n_rest - 1].k_hi) {
        uint16_t lo = 0, hi = (uint16_t)(s->n_rest - 1);
        while (lo < hi) {                       /* first class with k_hi >= k */
            uint16_t mid = (uint16_t)((lo + hi) / 2);
            if (s->rest[mid].k_hi < k) lo = (uint16_t)(mid + 1); else hi = mid;
        }
        *idx = lo;
        return 1;
    }
    for (i = 0; i < s->n_coast; i++) {          /* least m + settle among the coasts that fit */
        const seekopt_coast_class_t *c = &s->coast[i];
        if (c->k_lo <= k) {
            int64_t mi = coast_m(k, c->d_q);
            if (best < 0 || mi + c->settle < best) {
                best = mi + c->settle;
                *idx = i;
                *m = mi;
            }
        }
    }
    return best < 0 ? 0 : 2;
}

const seekopt_seek_set_t *seekopt_seek_find(uint32_t tpi, uint16_t member)
{
    unsigned i;
    for (i = 0; i < SEEKOPT_SEEK_N_SETS; i++)
        if (seekopt_seek_sets[i].tpi == tpi && seekopt_seek_sets[i].member == member)
            return &seekopt_seek_sets[i];
    return 0;
}

int32_t seekopt_seek_samples(const seekopt_seek_set_t *s, int32_t tracks)
{
    int32_t k = tracks < 0 ? -tracks : tracks;
    uint16_t idx = 0;
    int64_t m = 0;
    int kind;
    if (!s) return -1;
    if (tracks == 0) return 0;
    kind = pick(s, k, &idx, &m);
    if (kind == 1) {
        const seekopt_rest_class_t *c = &s->rest[idx];
        return c->ff_len > c->ref_len ? c->ff_len : c->ref_len;
    }
    if (kind == 2) {
        const seekopt_coast_class_t *c = &s->coast[idx];
        return (int32_t)m + (c->ff_len > c->ref_len ? c->ff_len : c->ref_len);
    }
    return -2;
}

int seekopt_seek_sample_set(const seekopt_seek_set_t *s, int32_t tracks, uint32_t k, int16_t *u_ff, int32_t *r)
{
    int32_t kk = tracks < 0 ? -tracks : tracks;
    int64_t sgn = tracks < 0 ? -1 : 1, m = 0, uu, rr, n;
    uint16_t idx = 0;
    int kind;
    *u_ff = 0;
    *r = 0;
    if (!s) return -1;
    if (tracks == 0) return 0;
    kind = pick(s, kk, &idx, &m);
    if (kind == 0) return -2;
    n = seekopt_seek_samples(s, tracks);
    if ((int64_t)k >= n) {
        *r = (int32_t)(sgn * (int64_t)kk * ((int64_t)1 << SEEKOPT_SEEK_REF_FRAC_BITS));
        return 0;
    }
    if (kind == 1) {
        const seekopt_rest_class_t *c = &s->rest[idx];
        int64_t R = (int64_t)k < (int64_t)c->ref_len ? (int64_t)s->ref[c->ref_off + k]
                    : (int64_t)c->k_hi * ((int64_t)1 << SEEKOPT_SEEK_REF_FRAC_BITS);
        uu = div_round(ff_at(s->ff + c->ff_off, c->ff_len, (int64_t)k) * kk, c->k_hi);
        rr = div_round(R * kk, c->k_hi);
    } else {
        const seekopt_coast_class_t *c = &s->coast[idx];
        int64_t num = (int64_t)kk * ((int64_t)1 << SEEKOPT_SEEK_REF_FRAC_BITS), den = m * c->d_q;
        const int16_t *f = s->ff + c->ff_off;
        const int32_t *g = s->ref + c->ref_off;
        uu = div_round((ff_at(f, c->ff_len, (int64_t)k) - ff_at(f, c->ff_len, (int64_t)k - m)) * num, den);
        rr = div_round((ramp_at(g, c->ref_len, c->d_q, (int64_t)k) - ramp_at(g, c->ref_len, c->d_q, (int64_t)k - m))
                       * num, den);
    }
    if (uu > 32767) uu = 32767;
    if (uu < -32767) uu = -32767;
    *u_ff = (int16_t)(sgn * uu);
    *r = (int32_t)(sgn * rr);
    return 1;
}

int seekopt_seek_sample(uint32_t tpi, int32_t tracks, uint32_t k, int16_t *u_ff, int32_t *r)
{
    return seekopt_seek_sample_set(seekopt_seek_find(tpi, 0), tracks, k, u_ff, r);
}
"""


def _banner(rule: SeekRule) -> str:
    m = rule.meta
    lines = [f"Generated by seekopt {m['tool_version']} (seekopt export) - do not edit.",
             "Seek tables for every integer seek length from 1 track to the full stroke, per TPI.",
             f"plant {m['plant_hash']}, controller {m['controller_hash']}, source {m['source']}, "
             f"designer {m['designer']}",
             f"sample rate {float(m['sample_rate_hz'])!r} Hz, Imax {float(m['imax_a'])!r} A, "
             f"settle band {float(m['settle_track'])!r} track",
             "u_ff: int16 Q15, I[A] = u * Imax / 32768, |u| <= 32767",
             f"r: int32, track from the seek start = r / 2^{rule.frac_bits}",
             "rule: rest class k_lo <= |K| <= k_hi: u = round(U(k)|K|/k_hi), r = round(R(k)|K|/k_hi);",
             "coast class: m = ceil(|K| 2^F / d_q), u = round((U(k)-U(k-m)) |K| 2^F / (m d_q)), same for R",
             "(R continued as a ramp); round half away from zero; negative seeks negate u and r."]
    return "/*\n" + "".join(f" * {x}\n" for x in lines) + " */\n"


def write_seek_c(rule: SeekRule, outdir, basename: str = C_BASENAME) -> list[Path]:
    """Write ``<basename>.h`` and ``<basename>.c`` into ``outdir``; returns their paths."""
    from identification.fileio import atomic_write_text as write_atomic
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    m, guard = rule.meta, basename.upper() + "_H"
    h = [_banner(rule), f"#ifndef {guard}\n#define {guard}\n\n#include <stdint.h>\n\n",
         f"#define SEEKOPT_SEEK_SAMPLE_RATE_HZ {float(m['sample_rate_hz'])!r}\n",
         f"#define SEEKOPT_SEEK_IMAX_A {float(m['imax_a'])!r}\n",
         "#define SEEKOPT_SEEK_FF_Q 15\n",
         f"#define SEEKOPT_SEEK_REF_FRAC_BITS {rule.frac_bits}\n",
         f"#define SEEKOPT_SEEK_N_SETS {len(rule.sets)}\n\n", _TYPES, "\n",
         "extern const seekopt_seek_set_t seekopt_seek_sets[SEEKOPT_SEEK_N_SETS];\n\n",
         "const seekopt_seek_set_t *seekopt_seek_find(uint32_t tpi, uint16_t member);\n",
         "int32_t seekopt_seek_samples(const seekopt_seek_set_t *set, int32_t tracks);\n",
         "int seekopt_seek_sample_set(const seekopt_seek_set_t *set, int32_t tracks, uint32_t k,\n"
         "                            int16_t *u_ff, int32_t *r);\n",
         "int seekopt_seek_sample(uint32_t tpi, int32_t tracks, uint32_t k, int16_t *u_ff, int32_t *r);\n\n",
         f"#endif /* {guard} */\n"]
    c = [_banner(rule), f'#include "{basename}.h"\n\n']
    descs = []
    for i, s in enumerate(rule.sets):
        ff, ref, rest, coast = [], [], [], []
        for cl in s.classes:
            rest.append(f"    {{{cl.k_lo}, {cl.k_hi}, {len(ff)}u, {len(ref)}u, {len(cl.ff_q15)}u, {len(cl.ref_q)}u, "
                        f"{min(cl.settle_samples, 65535)}u}},\n")
            ff += list(cl.ff_q15); ref += list(cl.ref_q)
        for cl in s.coasts:
            coast.append(f"    {{{cl.k_lo}, {cl.d_q}, {len(ff)}u, {len(ref)}u, {len(cl.ff_q15)}u, {len(cl.ref_q)}u, "
                         f"{min(cl.settle_samples, 65535)}u}},\n")
            ff += list(cl.ff_q15); ref += list(cl.ref_q)
        c.append(f"/* set {i}: {s.tpi} TPI, member {s.member}, lengths 1..{s.stroke}, "
                 f"{len(s.classes)} rest + {len(s.coasts)} coast classes, {s.table_bytes()} bytes */\n")
        c.append("static " + c_array("int16_t", f"ff_{i}", ff))
        c.append("static " + c_array("int32_t", f"ref_{i}", ref))
        c.append(f"static const seekopt_rest_class_t rest_{i}[{max(1, len(rest))}] = {{\n"
                 + ("".join(rest) or "    {0, 0, 0u, 0u, 0u, 0u, 0u}\n") + "};\n")
        c.append(f"static const seekopt_coast_class_t coast_{i}[{max(1, len(coast))}] = {{\n"
                 + ("".join(coast) or "    {0, 1, 0u, 0u, 0u, 0u, 0u}\n") + "};\n\n")
        descs.append(f"    {{{s.tpi}u, {s.member}u, {s.stroke}, {len(s.classes)}u, {len(s.coasts)}u, rest_{i}, coast_{i}, "
                     f"ff_{i}, ref_{i}}},\n")
    c.append("const seekopt_seek_set_t seekopt_seek_sets[SEEKOPT_SEEK_N_SETS] = {\n" + "".join(descs) + "};\n")
    c.append(_FUNCS)
    hp, cp = outdir / f"{basename}.h", outdir / f"{basename}.c"
    write_atomic(hp, "".join(h))
    write_atomic(cp, "".join(c))
    return [hp, cp]
