"""Every mission-file value is checked before anything starts, and the message names the key, the file and
what would be valid (a `[planner] weights` typo used to surface only after the whole mission had walked)."""

from __future__ import annotations

from pathlib import Path

import pytest

from psrmap.cli import main
from psrmap.mission.config import MissionError, load_config

SCOUT = '[[scouts]]\nid = "a"\nstart = [1, 1, 0]\ngoal = [2, 2]\n'


@pytest.mark.parametrize(
    ("toml", "message"),
    [
        ('[mission]\nsim_seconds = "ten"\n', "[mission] sim_seconds = 'ten': need a finite number"),
        ("[mission]\nres = nan\n", "[mission] res = nan: need a finite number"),
        ('[mission]\nsecure = "yes"\n', "[mission] secure = 'yes': need true or false"),
        ("[mission]\nshards = 1.5\n", "[mission] shards = 1.5: need an integer, 1..16"),
        ('[mission]\nmap = "a.b"\n', "map 'a.b' must match [A-Za-z0-9_-]+"),
        ("[terrain]\nseed = 1.5\n", "[terrain] seed = 1.5: need an integer"),
        ('[terrain]\nscene = "mars"\n', "scenes: lunar, ramps"),
        ("[terrain]\nseed = -1\n", "seed = -1: need an integer >= 0"),
        (
            "[planner]\nweights = { cot = 1.0, slpi = 2.0 }\n",
            "weights: unknown term 'slpi'; terms: distance, cot",
        ),
        ("[planner]\nweights = { cot = -1 }\n", "weights.cot = -1: need a finite number >= 0"),
        ('[planner]\nweights = "cot=1"\n', "[planner] weights = 'cot=1': need a table"),
        ('[planner]\nfrom = "2,2"\n', "[planner] from = '2,2': need [x, y] in metres"),
        ('[planner]\nunknown = "guess"\n', "policies: forbid, penalty, infer"),
    ],
)
def test_a_bad_value_names_key_file_and_what_is_valid(tmp_path: Path, toml: str, message: str) -> None:
    path = tmp_path / "m.toml"
    path.write_text(toml + SCOUT)
    with pytest.raises(MissionError) as exc:
        load_config(path)
    assert str(exc.value).startswith(f"{path}: "), exc.value
    assert message in str(exc.value)


def test_a_weights_typo_stops_the_mission_before_anything_starts(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "m.toml").write_text("[planner]\nweights = { slpi = 2.0 }\n" + SCOUT)
    with pytest.raises(SystemExit) as exc:
        main(["mission", "--config", "m.toml"])
    assert exc.value.code == 2
    assert "m.toml: [planner] weights: unknown term 'slpi'" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()  # no router, no scout: nothing walked
