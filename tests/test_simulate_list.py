"""`fgnav simulate --list`: every built-in scenario once, with its sensors; no scenario errors."""

import pytest

from fgnav.cli import main
from fgnav.scenarios import builtin_names, load_scenario


def test_list_prints_every_builtin_with_its_sensors(capsys):
    assert main(["simulate", "--list"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    names = builtin_names()
    assert len(lines) == len(names)
    for name in names:
        mine = [ln for ln in lines if ln.split()[0] == name]
        assert len(mine) == 1, name
        for s in load_scenario(name).sensors:
            assert s.kind in mine[0].split("sensors:")[1], (name, s.kind)
        assert "orbit: " + load_scenario(name).centre in mine[0]


def test_simulate_without_scenario_still_errors(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["simulate"])
    assert exc.value.code == 2
    assert "required" in capsys.readouterr().err
