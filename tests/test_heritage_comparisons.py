"""Heritage figures compared fairly: `fgnav demo` compares its run with Pan & Yao 2017's
figure only at the same rate and length, and otherwise says plainly that the rates differ;
`fgnav schemes refraction` shows MADAN's figure on the row it can be compared with."""

from fgnav.cli import main
from fgnav.commands.demo import PAN_YAO_2017, heritage_note


def test_same_rate_and_length_compares():
    note = heritage_note(PAN_YAO_2017["step_s"], PAN_YAO_2017["duration_h"])
    assert "the same rate and length" in note and "not comparable" not in note


def test_other_rate_says_so():
    note = heritage_note(10.0, 4.0)
    assert "every 10 s" in note and "100x fewer" in note and "not comparable" in note
    assert "fgnav demo --step-s 0.1" in note
    assert "20x fewer" in heritage_note(1.0, 2.0)


def test_demo_prints_the_rate_difference(capsys):
    assert main(["demo", "--duration-h", "0.5", "--step-s", "60", "--methods", "batch"]) == 0
    out = capsys.readouterr().out
    assert "sampled every 0.1 s" in out and "This run samples every 60 s" in out
    assert "(10 Hz)" not in out  # the old unqualified comparison


def test_refraction_table_has_the_madan_column():
    """The heritage figure sits on the row with both error sources (a flown system has both),
    and the note says what MADAN is."""
    from fgnav.analysis.scheme_studies import MADAN_POSITION_M, format_refraction_table

    row = {"gamma_halfwidth_arcsec": 1.0, "sigma_model_m": 100.0, "n_fixes": 10,
           "fix_median_m": 500.0, "fix_rms_m": 900.0, "ekf_position_rms_m": 250.0,
           "ekf_position_rms_settled_m": 20.0, "batch_position_rms_m": 15.0,
           "batch_velocity_rms_mps": 0.015, "batch_sigma_position_rms_m": 14.0,
           "batch_nees_mean": 6.0, "settle_s": 1800.0}
    rows = [dict(row, case="both"), dict(row, case="angle only")]
    lines = format_refraction_table(rows).splitlines()
    assert lines[0].split()[-2:] == ["MADAN", "m"]
    assert lines[2].split()[-1] == f"{MADAN_POSITION_M:.0f}" and lines[3].split()[-1] == "-"
    assert "Multimission Attitude Determination and Autonomous Navigation" in "\n".join(lines)
