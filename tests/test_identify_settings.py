"""Tests for identification.estimate.settings and the option mapping of identify()."""
import json

import pytest

from identification.estimate.identify import make_settings
from identification.estimate.settings import IdentifySettings, PaperSettings, RobustSettings


@pytest.mark.parametrize("settings", [PaperSettings(), PaperSettings(prony_order=4, freq_range=(200, 9000)),
                                      RobustSettings(),
                                      RobustSettings(holdout_every=0, periodic=220, scan_zetas=(0.02,),
                                                     zeta_bounds=(1e-3, 0.5), cov="cluster", t_min=4.0)])
def test_settings_json_round_trip(settings):
    text = settings.to_json()
    assert json.loads(text)["method"] == settings.method
    back = IdentifySettings.from_json(text)
    assert type(back) is type(settings) and back == settings


def test_options_map_onto_the_method_settings():
    s = make_settings("paper", prony_order=5)
    assert isinstance(s, PaperSettings) and s.prony_order == 5 and s.holdout_every == 5
    s = make_settings(None, RobustSettings(t_min=4.0), max_modes=3)
    assert isinstance(s, RobustSettings) and (s.t_min, s.max_modes) == (4.0, 3)
    assert make_settings() == RobustSettings()
    assert make_settings("robust").band(26400.0) == (100.0, pytest.approx(0.47 * 26400.0))
    assert make_settings("robust", freq_range=[150, 9000]).band(26400.0) == (150.0, 9000.0)


@pytest.mark.parametrize("call, match", [
    (lambda: make_settings("robust", max_mode=3), r"unknown option\(s\) \['max_mode'\] for method 'robust'"),
    (lambda: make_settings("paper", max_modes=3), r"unknown option\(s\) \['max_modes'\] for method 'paper'"),
    (lambda: make_settings("magic"), "method must be 'robust' or 'paper'"),
    (lambda: make_settings("paper", RobustSettings()), "contradicts RobustSettings"),
    (lambda: make_settings("robust", cov="white"), "cov must be"),
    (lambda: make_settings("robust", periodic="yes"), "periodic must be"),
    (lambda: make_settings("robust", ar_order=-1), "ar_order"),
    (lambda: make_settings("robust", freq_range=(5000, 100)), "freq_range"),
    (lambda: make_settings("robust", freq_high_fraction=0.6), "below Nyquist"),
    (lambda: IdentifySettings.from_dict({"method": "x"}), "method must be"),
])
def test_bad_options_one_line_value_error(call, match):
    with pytest.raises(ValueError, match=match) as err:
        call()
    assert "\n" not in str(err.value)
