"""Issue 12, item 24: the acoustic receiver uses the site's temperature for the speed of sound.

Site seed 3 with its air at −10 °C and at 35 °C (the simulator propagates with the same
``[atmosphere] temperature_c`` the receiver reads), a survey of 20 m cells with 6 s static
captures. The range the receiver forms, c(T_site)·(arrival − emission − δ_fix), against the
simulator's direct path of LOS chirps at 10–25 m: median |error| < 3 cm (measured 1.1 cm at
both temperatures, 48 and 60 chirps). The same arrivals ranged with c(20 °C) read 0.78 m
(−10 °C) and 0.36 m (35 °C) off: the check the test also makes, so that a receiver falling
back to 20 °C (5.3 % short at −10 °C, 2.4 % long at 35 °C) fails it.
"""

from __future__ import annotations

import csv
import dataclasses

import numpy as np
import pytest

from features.acoustic.features import analyse_audio
from features.acoustic.timing import speed_of_sound_m_s, timing_from_walk
from features.site import load_site, save_site
from features.walk import load_walk


def _range_errors(survey, c_rx):
    site = load_site(survey / "site.toml")
    errors = []
    for cell in sorted(p for p in (survey / "cells").iterdir() if (p / "audio.wav").is_file()):
        timing = timing_from_walk(load_walk(cell / "cell.toml"), site)
        res = analyse_audio(cell / "audio.wav", site, timing, keep_frames=True)
        truth = {(int(r["beacon_id"]), round(float(r["emit_t_s"]), 6)): r
                 for r in csv.DictReader(open(cell / "audio_truth.csv"))}
        for fr in res.frames:
            if fr.fix is None:
                continue
            for d in fr.detections:
                t = truth.get((d.beacon_id, round(d.tx_s, 6)))
                if t is None or t["first_path"] != "direct" or not 10.0 <= float(t["direct_m"]) <= 25.0:
                    continue
                errors.append(c_rx * (d.arrival_s - d.tx_s - fr.fix.clock_offset_s) - float(t["direct_m"]))
    return np.array(errors)


@pytest.fixture(scope="module", params=[-10.0, 35.0])
def cold_or_hot_survey(request, tmp_path_factory):
    from simulation.site.layout import generate_site
    from simulation.survey import simulate_survey

    root = tmp_path_factory.mktemp(f"t{request.param:+.0f}")
    site = generate_site(3)
    site = dataclasses.replace(site, atmosphere=dataclasses.replace(site.atmosphere, temperature_c=request.param))
    save_site(site, root / "site.toml")
    # The stated air and ideal transducers: this checks the receiver's use of the site's temperature,
    # not the simulator's realism (wind and the crew's thermometer error alone would move ranges by cm).
    survey = simulate_survey(root, root / "survey", seed=1, cell_size_m=20.0, capture_s=6.0, progress=False,
                             writers=("simulation.acoustic.stream:write_audio",),
                             options={"acoustic_air": False, "acoustic_hardware": False})
    return request.param, survey


def test_los_ranges_at_site_temperature(cold_or_hot_survey):
    temperature_c, survey = cold_or_hot_survey
    err = _range_errors(survey, speed_of_sound_m_s(temperature_c))
    assert len(err) >= 20
    assert np.median(np.abs(err)) < 0.03
    # The same arrivals read with 20 °C: what the test would catch.
    wrong = _range_errors(survey, speed_of_sound_m_s(20.0))
    assert np.median(np.abs(wrong)) > 0.1
