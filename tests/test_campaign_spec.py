"""Study files: every key validated, unknown keys rejected, each error a UserError naming the
file and the key (fgnav.campaign.spec)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from fgnav.campaign import builtin_studies, load_study, study_runs
from fgnav.campaign.tasks import NavigateParams
from fgnav.errors import InputFormatError

NAVIGATE = """
name = "t"
task = "navigate"
report = "seed002-noise"
methods = ["batch", "ekf"]
seeds = [0, 1]
[fixed]
scenario = "gto-transfer"
step_s = 120.0
duration_h = 1.0
[grid]
sigma_deg = [0.01, 0.05]
[reference]
max_sigma_deg = 0.05
final_position_km = 4.0
final_velocity_mps = 0.5
"""

OBSERVABILITY = """
name = "o"
task = "observability"
report = "observability"
[fixed]
window_h = 1.0
[grid]
step_s = [1.0, 10.0]
"""

NEES = """
name = "n"
task = "navigate"
report = "nees"
methods = ["batch"]
[fixed]
step_s = 120.0
[reference]
alpha = 0.05
"""


def _load(tmp_path, text):
    path = tmp_path / "study.toml"
    path.write_text(text)
    return path, load_study(path)


BAD = [
    # (base, old, new, the key the message must name)
    (NAVIGATE, 'name = "t"', 'name = "t"\ncolour = 1', "colour"),
    (NAVIGATE, 'name = "t"', "name = 3", "name"),
    (NAVIGATE, 'name = "t"', 'name = "t"\ndescription = ["a"]', "description"),
    (NAVIGATE, 'task = "navigate"', 'task = "juggle"', "task"),
    (NAVIGATE, 'report = "seed002-noise"', 'report = "visibility"', "report"),
    (NAVIGATE, 'methods = ["batch", "ekf"]', 'methods = ["magic"]', "methods"),
    (NAVIGATE, 'methods = ["batch", "ekf"]', 'methods = ["ekf", "ekf"]', "methods"),
    (NAVIGATE, 'methods = ["batch", "ekf"]\n', "", "methods"),
    (NAVIGATE, "seeds = [0, 1]", "seeds = []", "seeds"),
    (NAVIGATE, "seeds = [0, 1]", "seeds = [1, 1]", "seeds"),
    (NAVIGATE, "seeds = [0, 1]", "seeds = [0.5]", "seeds"),
    (NAVIGATE, "seeds = [0, 1]", "seeds = {start = 0}", "seeds.count"),
    (NAVIGATE, "seeds = [0, 1]", "seeds = {start = 0, count = 2, step = 3}", "seeds.step"),
    (NAVIGATE, "seeds = [0, 1]", "seeds = {start = 0, count = 0}", "seeds.count"),
    (NAVIGATE, "seeds = [0, 1]", 'seeds = [0, 1]\nsave_curves = "yes"', "save_curves"),
    (NAVIGATE, "step_s = 120.0", "colour = 1", "fixed.colour"),
    (NAVIGATE, "step_s = 120.0", 'step_s = "fast"', "fixed.step_s"),
    (NAVIGATE, "step_s = 120.0", "step_s = -1.0", "fixed.step_s"),
    (NAVIGATE, "step_s = 120.0", "step_s = nan", "fixed.step_s"),
    (NAVIGATE, 'scenario = "gto-transfer"', "scenario = 7", "fixed.scenario"),
    (NAVIGATE, 'scenario = "gto-transfer"', 'third_body = "yes"', "fixed.third_body"),
    (NAVIGATE, 'scenario = "gto-transfer"', 'method = "ekf"', "fixed.method"),
    (NAVIGATE, "sigma_deg = [0.01, 0.05]", "colour = [1]", "grid.colour"),
    (NAVIGATE, "sigma_deg = [0.01, 0.05]", "sigma_deg = []", "grid.sigma_deg"),
    (NAVIGATE, "sigma_deg = [0.01, 0.05]", "sigma_deg = 0.01", "grid.sigma_deg"),
    (NAVIGATE, "sigma_deg = [0.01, 0.05]", "sigma_deg = [0.01, true]", "grid.sigma_deg[1]"),
    (NAVIGATE, "sigma_deg = [0.01, 0.05]", "sigma_deg = [0.01, 0.01]", "grid.sigma_deg"),
    (NAVIGATE, "sigma_deg = [0.01, 0.05]", "step_s = [10.0]", "grid"),
    (NAVIGATE, "max_sigma_deg = 0.05", "max_sigma_deg = 0.05\nbeta = 1", "reference.beta"),
    (NAVIGATE, "max_sigma_deg = 0.05\n", "", "reference.max_sigma_deg"),
    (NAVIGATE, "final_position_km = 4.0", "final_position_km = -4.0", "reference.final_position_km"),
    (NAVIGATE, "final_position_km = 4.0", 'final_position_km = "4 km"', "reference.final_position_km"),
    (OBSERVABILITY, 'name = "o"', 'name = "o"\nmethods = ["batch"]', "methods"),
    (OBSERVABILITY, "step_s = [1.0, 10.0]", "sigma_deg = [0.01]", "fixed.step_s"),
    (OBSERVABILITY, "window_h = 1.0", "n_samples = 2.5", "fixed.n_samples"),
    (OBSERVABILITY, "window_h = 1.0", "duration_h = 1.0", "fixed.duration_h"),
    (NEES, "[reference]\nalpha = 0.05\n", "", "reference"),
    (NEES, "alpha = 0.05", "alpha = 1.5", "reference.alpha"),
    (NEES, "alpha = 0.05", "alpha = [0.05]", "reference.alpha"),
]


@pytest.mark.parametrize("base,old,new,key", BAD, ids=[f"{b[3]}:{b[2][:30]}" for b in BAD])
def test_bad_key_or_value_names_file_and_key(tmp_path, base, old, new, key):
    assert old in base
    path = tmp_path / "bad.toml"
    path.write_text(base.replace(old, new))
    with pytest.raises(InputFormatError) as e:
        load_study(path)
    assert str(path) in str(e.value)
    assert e.value.column == key, str(e.value)


def test_list_valued_parameter_only_in_fixed(tmp_path):
    text = ('name = "v"\ntask = "visibility"\nreport = "visibility"\nmethods = ["batch"]\n'
            '[grid]\norbit = ["leo-500"]\nring_deg = [[120.0, 160.0]]\n'
            '[reference]\nband_km = [98.3, 985.6]\nearth_radii_km = [6371.0]\n')
    path = tmp_path / "v.toml"
    path.write_text(text)
    with pytest.raises(InputFormatError, match="grid.ring_deg"):
        load_study(path)
    path.write_text(text.replace("ring_deg = [[120.0, 160.0]]", "").replace(
        "[grid]", "[fixed]\nring_deg = [120.0]\n[grid]"))
    with pytest.raises(InputFormatError, match=r"fixed.ring_deg.*a list of 2 numbers"):
        load_study(path)
    path.write_text(text.replace("ring_deg = [[120.0, 160.0]]", "").replace("[98.3, 985.6]", "[985.6, 98.3]"))
    with pytest.raises(InputFormatError, match="reference.band_km"):
        load_study(path)


def test_table5_reference_rows_match_the_angle_errors(tmp_path):
    text = Path(load_study("seed000-table5").source).read_text()
    bad = tmp_path / "t5.toml"
    bad.write_text(text.replace("4000 = [0.208, 0.903, 1.389, 1.805]", "4000 = [0.208, 0.903]"))
    with pytest.raises(InputFormatError, match="reference.seed_km.4000"):
        load_study(bad)


def test_cli_reports_a_bad_study_without_traceback(tmp_path, capsys):
    from fgnav.cli import main

    path = tmp_path / "bad.toml"
    path.write_text(NAVIGATE.replace("step_s = 120.0", "step_s = 0.0"))
    assert main(["campaign", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("fgnav: error:") and "fixed.step_s" in err and "> 0" in err
    assert "Traceback" not in err and not (tmp_path / "o").exists()


def test_values_are_typed(tmp_path):
    # an integer written for a float parameter is a float; run ids and params carry the type
    _, s = _load(tmp_path, NAVIGATE.replace("step_s = 120.0", "step_s = 120"))
    assert s.fixed["step_s"] == 120.0 and isinstance(s.fixed["step_s"], float)
    runs = study_runs(s)
    assert [r.run_id for r in runs][:2] == ["sigma_deg=0.01;method=batch;seed=0", "sigma_deg=0.01;method=batch;seed=1"]
    p = runs[0].params
    assert isinstance(p, NavigateParams) and p.step_s == 120.0 and p.method == "batch" and p.seed == 0
    assert p["sigma_deg"] == 0.01 and p.q_m2_s3 is None
    with pytest.raises(KeyError):
        p["colour"]
    with pytest.raises(AttributeError):
        p.seed = 3  # frozen
    assert s.reference.final_position_km == 4.0


def test_builtin_studies_state_their_reference_figures():
    for name in builtin_studies():
        s = load_study(name)
        assert s.reference is not None, name  # every built-in study states its figures
        json.dumps(s.reference_json())          # and study.json can record them
    assert load_study("gto-nees").reference.alpha == 0.05
    assert load_study("seed002-observability").reference.rank == 6
