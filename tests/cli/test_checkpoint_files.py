"""Checkpoints we load never run code, and damaged ones give one clear error."""

from __future__ import annotations

import builtins
import math

import pytest
import torch
from click.testing import CliRunner

from optix_e2e.cli import main
from optix_e2e.isp.proxy import ISPProxy
from optix_e2e.isp.software import SoftwareISP
from optix_e2e.surrogate.checkpoint import FORMAT, OpticsSurrogate, SurrogateFileError


class _Payload:
    """Unpickling this creates the marker file: what a crafted checkpoint would do."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (builtins.exec, (f"open({self.marker!r}, 'w').close()",))


def _malicious(path, marker, fmt):
    torch.save({"format": fmt, "state_dict": {}, "config": {}, "payload": _Payload(marker)}, path)
    return path


def _load_surrogate(p):
    OpticsSurrogate.load(p)


def _load_proxy(p):
    ISPProxy.load(p)


def _load_software(p):
    SoftwareISP.load(p)


def _resume_training(p):
    from optix_e2e.surrogate.train import TrainConfig, train

    train(p.parent / "no-dataset", p.parent, TrainConfig(steps=1), progress=False)


@pytest.mark.parametrize(
    "load, name, fmt",
    [
        (_load_surrogate, "surrogate.pt", FORMAT),
        (_load_proxy, "proxy.pt", "optix-isp-proxy/1"),
        (_load_software, "software_isp.pt", "optix-software-isp/1"),
        (_resume_training, "state.pt", None),
    ],
)
def test_malicious_checkpoint_runs_nothing(tmp_path, load, name, fmt):
    marker = tmp_path / "pwned"
    path = _malicious(tmp_path / name, marker, fmt)
    with pytest.raises((SurrogateFileError, ValueError)) as err:
        load(path)
    assert not marker.exists(), "loading the checkpoint ran the code inside it"
    assert str(path) in str(err.value)


def test_malicious_checkpoint_cli_one_error_line(tmp_path):
    marker = tmp_path / "pwned"
    path = _malicious(tmp_path / "surrogate.pt", marker, FORMAT)
    res = CliRunner().invoke(main, ["surrogate", "eval", str(path), str(tmp_path)])
    assert res.exit_code == 1 and not marker.exists()
    assert res.output.startswith("Error: ") and res.output.count("\n") == 1, res.output


def test_shipped_checkpoints_load_as_plain_data():
    """The shipped files load under weights_only=True and give finite weights."""
    m = OpticsSurrogate.load("paper-triplet-v1")
    p = ISPProxy.load()
    for net in (m, p):
        assert all(torch.isfinite(v).all() for v in net.state_dict().values() if v.is_floating_point())
    assert math.isfinite(m.pitch_um)


# -- item 8: damaged checkpoints and out-of-range options give one Error line ---------------


def _one_error(res, *needles, code=1):
    """The command failed cleanly: exit status ``code``, no traceback, one ``Error:`` line
    naming each of ``needles``."""
    assert isinstance(res.exception, SystemExit) and res.exit_code == code, (res.exit_code, res.output)
    errors = [line for line in res.output.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and "Traceback" not in res.output, res.output
    for n in needles:
        assert n in errors[0], (n, errors[0])
    return errors[0]


def _damaged(src, path, change):
    st = torch.load(src, weights_only=True)
    change(st)
    torch.save(st, path)
    return path


def _nan_first_weight(st):
    sd = st["state_dict"]
    k = next(k for k, v in sd.items() if v.is_floating_point())
    sd[k] = sd[k].clone()
    sd[k].view(-1)[0] = float("nan")


def _drop(key):
    return lambda st: st.pop(key)


def _set(key, value):
    return lambda st: st.__setitem__(key, value)


def _drop_weight(st):
    st["state_dict"].pop(next(iter(st["state_dict"])))


@pytest.mark.parametrize(
    "change, needle",
    [
        (_set("config", {"pattern": "XYZ", "base": 32}), "config"),
        (_set("config", {"base": 64}), "weights do not match"),  # valid config, other shapes
        (_set("config", "RGGB"), "no config"),
        (_drop("state_dict"), "no state_dict"),
        (_drop_weight, "missing"),
        (_nan_first_weight, "non-finite"),
        (_set("space", 3), "hyperparameter space"),
    ],
)
def test_isp_eval_damaged_proxy(tmp_path, change, needle):
    from optix_e2e.isp.proxy import BUNDLED

    path = _damaged(BUNDLED, tmp_path / "proxy.pt", change)
    res = CliRunner().invoke(
        main, ["isp", "eval", str(path), "--size", "32", "--param-sets", "0", "--photo", "astronaut"]
    )
    _one_error(res, str(path), needle)


@pytest.mark.parametrize(
    "change, needle",
    [
        (_nan_first_weight, "non-finite"),
        (
            _set(
                "config",
                {
                    "n_params": 19,
                    "channels": 3,
                    "psf_size": 21,
                    "hidden": 128,
                    "depth": 4,
                    "base_channels": 64,
                    "n_up": 2,
                },
            ),
            "weights do not match",
        ),
        (_set("config", {"n_params": 19, "nonsense": 1}), "config"),
        (_set("param_mean", [float("nan")] * 19), "param_mean"),
        (_set("param_min", [0.0] * 3), "param_min"),
        (_set("manifest", "text"), "manifest"),
    ],
)
def test_surrogate_eval_damaged_checkpoint(tmp_path, change, needle):
    from optix_e2e.surrogate.checkpoint import bundled_path

    path = _damaged(bundled_path("paper-triplet-v1"), tmp_path / "surrogate.pt", change)
    res = CliRunner().invoke(main, ["surrogate", "eval", str(path), str(tmp_path)])
    _one_error(res, str(path), needle)


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--temperature", "1e6"], "temperature_c"),  # 2 ** (1e6 / 7) overflows
        (["--temperature", "1000"], "dark frames saturate"),
        (["--exposure-s", "1e6"], "dark frames saturate"),
        (["--exposure-s", "1e-300"], "beyond float32"),
        (["--gain", "1e-9"], "spans"),
        (["--gain", "1e9"], "saturate"),
        (["--low-light", "1e300"], "saturate"),
    ],
)
def test_sensor_ptc_unmeasurable_settings(args, needle):
    res = CliRunner().invoke(main, ["sensor", "ptc", "--patch", "16", "--levels", "10", *args])
    _one_error(res, needle)


@pytest.mark.parametrize(
    "cmd",
    [
        ["sensor", "ptc", "--temperature", "-300"],
        ["sensor", "ptc", "--gain", "nan"],
        ["sensor", "ptc", "--exposure-s", "inf"],
        ["sensor", "ptc", "--seed", "99999999999999999999999"],
        ["sensor", "ptc", "--patch", "100000"],
        ["isp", "eval", "--size", "100000"],
        ["isp", "tune", "--perceptual-weight", "nan"],
        ["isp", "train-proxy", "--out", "x", "--lr", "inf"],
        ["surrogate", "train", ".", "--out", "x", "--hidden", "1000000000"],
        ["surrogate", "train", ".", "--out", "x", "--lr", "nan"],
    ],
)
def test_numeric_options_range_checked(cmd):
    """Options that would overflow, allocate without bound or feed NaN are refused by click
    before anything runs (click's usage error: exit 2, one Error line naming the option)."""
    res = CliRunner().invoke(main, cmd)
    _one_error(res, "--" + cmd[-2].lstrip("-"), code=2)


def test_sensor_preset_temperature_checked():
    from optix_e2e.sensor import get_preset
    from optix_e2e.sensor.emva import dark_current_mean

    p = get_preset("imx249")
    with pytest.raises(ValueError, match="overflows"):
        p.with_(temperature_c=1e6)
    with pytest.raises(ValueError, match="absolute zero"):
        dark_current_mean(p, temperature_c=-274)
    # Eq. 4 still holds where it is defined: one doubling per doubling_c
    assert dark_current_mean(p, temperature_c=p.t_ref_c + p.doubling_c) == pytest.approx(
        2 * dark_current_mean(p, temperature_c=p.t_ref_c), rel=1e-12
    )
