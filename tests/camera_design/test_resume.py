"""A run folder resumes as it was made: every setting the user does not give comes from its
config.json (config.resume_settings), whatever today's defaults; a given setting is held to
the folder's; a folder that does not say how it was made is refused in one line."""

import json

import pytest

from optix_e2e.camera_design.config import (
    DesignConfig,
    check_run_dir,
    load_config,
    make_config,
    read_run_config,
    resume_settings,
    run_config,
)
from optix_e2e.errors import InputError


def test_the_defaults_each_task_starts_from():
    for budget in ("smoke", "quick", "full"):
        assert make_config(budget).optics == "exact"
        assert make_config(budget, task="low-light").optics == "exact"
        assert make_config(budget).guard == "barrier"
        assert make_config(budget).train_positions == "radius"
        assert make_config(budget).lens_steps == "sigmoid"
        det = make_config(budget, task="detection")
        assert det.lens_steps == "range"
        if budget == "smoke":
            assert (det.optics, det.space) == ("surrogate", "")
        else:
            assert (det.optics, det.space) == ("exact", "paper-triplet-detect-wide")
    assert make_config("quick", task="detection").lr_optics == 5e-2


def test_what_the_user_gave_is_named():
    cfg, given = load_config(None, task="iq-software", seed=3, optics=None)
    assert cfg.budget == "quick" and given == {"task", "seed"}  # no --budget: not given
    _, given = load_config("full", task="detection")
    assert given == {"task", "budget"}


def test_a_folder_made_under_other_defaults_resumes_with_its_own_settings(tmp_path):
    """The folder's values for every setting the command leaves alone: a run made under the
    projection, the surrogate and a lens rate that is no budget's default today goes on with them."""
    made = make_config("quick", task="detection", guard="project", optics="surrogate", space="", lr_optics=3e-2)
    check_run_dir(tmp_path / "run", made)
    today, given = load_config(None, task="detection")
    assert (today.guard, today.optics, today.lr_optics) == ("barrier", "exact", 5e-2)
    resumed = resume_settings(tmp_path / "run", today, given)
    assert resumed == made
    check_run_dir(tmp_path / "run", resumed)  # accepted
    # a setting the user gives is held to the folder's
    other, given = load_config(None, task="detection", seed=4)
    with pytest.raises(InputError, match="seed: 0 -> 4"):
        check_run_dir(tmp_path / "run", resume_settings(tmp_path / "run", other, given))
    same, given = load_config(None, task="detection", lr_optics=3e-2)
    check_run_dir(tmp_path / "run", resume_settings(tmp_path / "run", same, given))
    # a new folder: today's settings; every setting counted as given (None): held to the folder
    assert resume_settings(tmp_path / "new", today, given) == today
    assert resume_settings(tmp_path / "run", today, None) == today
    with pytest.raises(InputError, match="guard: 'project' -> 'barrier'"):
        check_run_dir(tmp_path / "run", today)
    assert run_config(tmp_path / "run") == made


def test_a_folder_that_does_not_say_how_it_was_made_is_refused_in_one_line(tmp_path):
    check_run_dir(tmp_path / "run", make_config("smoke"))
    path = tmp_path / "run" / "config.json"
    made = json.loads(path.read_text())
    del made["lens_steps"], made["guard"]
    path.write_text(json.dumps(made))
    with pytest.raises(InputError, match="does not say how the run was made for guard, lens_steps"):
        resume_settings(tmp_path / "run", make_config("smoke"), frozenset())
    with pytest.raises(InputError, match="does not say how the run was made"):
        check_run_dir(tmp_path / "run", make_config("smoke"))
    path.write_text("[1, 2]")
    with pytest.raises(InputError, match="is damaged"):
        read_run_config(tmp_path / "run")
    path.write_text(json.dumps({**DesignConfig().to_json(), "gone": 1}))
    with pytest.raises(InputError, match="settings this version does not have: gone"):
        run_config(tmp_path / "run")
    with pytest.raises(InputError, match="gone: 1 -> None"):
        check_run_dir(tmp_path / "run", make_config("quick"))


def test_a_setting_the_optimizer_does_not_read_is_refused(tmp_path):
    with pytest.raises(InputError, match="lr_optics given on the command line, but the vanilla optimizer does not use"):
        make_config("smoke", optimizer="vanilla", lr_optics=0.05)
    f = tmp_path / "v.toml"
    f.write_text('optimizer = "vanilla"\nbeta_isp = 0.5\nlr_isp_net = 1e-3\n')
    with pytest.raises(InputError, match=r"beta_isp, lr_isp_net given in .*v.toml, but the vanilla"):
        make_config("smoke", f)
    with pytest.raises(InputError, match="lr_vanilla given on the command line, but the alg1 optimizer"):
        make_config("smoke", lr_vanilla=1e-3)
    # a budget's own rate is no user's setting: vanilla runs at the detection quick budget
    assert make_config("quick", task="detection", optimizer="vanilla").lr_vanilla == 1e-3
    assert make_config("smoke", optimizer="vanilla", lr_vanilla=2e-3).lr_vanilla == 2e-3
