"""A task is one plugin (tasks/plugin.py) in one registry (tasks/registry.py): a toy task, one
module's worth of code below plus one ``register`` line, runs `optix design` end to end at the
smoke budget with its own definition, budget settings, hooks and help line."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest
from click.testing import CliRunner

from optix_e2e.camera_design.config import make_config
from optix_e2e.camera_design.image_quality import ImageQualityHooks
from optix_e2e.camera_design.run import run_design
from optix_e2e.errors import InputError
from optix_e2e.tasks import TaskPlugin, get_task, plugin, plugins, register
from optix_e2e.tasks.registry import unregister

pytestmark = pytest.mark.slow  # a whole design run


# ---- the toy task's module: an image-quality task scored on L1 alone, one line more in the log ----
class ToyHooks(ImageQualityHooks):
    def describe(self):
        return "toy: " + super().describe()

    @staticmethod
    def summary_lines(results):
        return ["toy task: " + f"{results['end_to_end']['psnr_db']:.2f} dB"]


TOY = TaskPlugin(
    replace(get_task("iq-software"), name="iq-toy", lpips_weight=0.0, description="a toy: L1 only"),
    ToyHooks,
    help="a toy task for the tests (L1 alone)",
    budgets={"smoke": {"n_finetune": 1, "eval_procedural": 0}},
)
# ---- end of the module ----


@pytest.fixture
def toy():
    register(TOY)  # the one registry line
    yield TOY
    unregister(TOY.name)


def test_a_toy_task_is_one_module_and_one_registry_line(toy, tmp_path, optix):
    assert plugin("iq-toy") is toy and toy in plugins() and get_task("iq-toy").lpips_weight == 0.0
    cfg = make_config("smoke", task="iq-toy", threads=1)
    assert (cfg.n_finetune, cfg.eval_procedural) == (1, 0)  # its budget's settings
    assert make_config("smoke", threads=1).n_finetune == 2  # no other task's
    lines = []
    res = run_design(cfg, tmp_path / "run", progress=False, log=lines.append)
    assert res["task"] == "iq-toy" and res["description"] == "a toy: L1 only"
    assert lines[0].startswith("[1/4] toy: end-to-end training: iq-toy")  # its hooks
    assert res["training"]["end_to_end"]["steps"] == cfg.total_steps == 5
    saved = json.loads((tmp_path / "run" / "results.json").read_text())
    assert saved["end_to_end"]["psnr_db"] == pytest.approx(res["end_to_end"]["psnr_db"])
    # the command line: its name, its help line, its summary
    from optix_e2e.cli import main

    runner = CliRunner()
    assert "a toy task for the tests (L1 alone)" in runner.invoke(main, ["design", "--help"]).output
    r = runner.invoke(
        main, ["design", "iq-toy", "--out", str(tmp_path / "run"), "--budget", "smoke", "--threads", "1", "--quiet"]
    )
    assert r.exit_code == 0, r.output
    assert "toy task: " in r.output  # a finished run: reported again, nothing trained


def test_the_registry_refuses_a_second_task_of_a_name_and_names_the_known_ones(toy):
    with pytest.raises(InputError, match="registered already"):
        register(toy)
    with pytest.raises(InputError, match="built-in task"):
        unregister("detection")
    with pytest.raises(InputError, match="unknown task 'iq-tyo': known tasks are iq-software, .*, iq-toy"):
        plugin("iq-tyo")
    assert [p.name for p in plugins()][:4] == ["iq-software", "iq-hardware", "low-light", "detection"]
