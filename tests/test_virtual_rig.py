"""The first virtual rig: deterministic, with the thesis's core physics."""

from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from piezopress.acquisition import rig_physics as phys
from piezopress.acquisition.rig_config import RigConfig, load_rig, parse_rig
from piezopress.acquisition.virtual_rig import VirtualRig
from piezopress.errors import BackendError, ConfigError

ROOT = Path(__file__).resolve().parents[1]


def run(rig, v, fs, label="r", preload=50.0):
    return rig.run(np.asarray(v, float), fs, preload_n=preload, label=label).channels


def test_shipped_rig_file_equals_defaults():
    assert load_rig(ROOT / "rigs" / "thesis-press.toml").as_dict() == RigConfig().as_dict()


def test_same_seed_same_data_and_label_changes_noise():
    rig = VirtualRig()
    v = np.full(2000, 40.0)
    a, b = run(rig, v, 20_000.0, "x"), run(VirtualRig(), v, 20_000.0, "x")
    np.testing.assert_array_equal(a["force_n"], b["force_n"])  # the same plan on the same rig file: the same data
    again = run(rig, v, 20_000.0, "x")  # a repeat on the same rig: new noise, as on a real press
    assert not np.array_equal(a["force_n"], again["force_n"])
    assert abs(np.mean(again["force_n"]) - np.mean(a["force_n"])) < 0.1
    c = run(rig, v, 20_000.0, "y")
    assert not np.array_equal(a["force_n"], c["force_n"])
    other_seed = VirtualRig(RigConfig().replace(rig={"seed": 1}))
    assert not np.array_equal(a["force_n"], run(other_seed, v, 20_000.0, "x")["force_n"])


def test_load_cell_quantization_and_noise():
    # 12 bits over +/-10 V at 10.003 mV/N: steps of 0.488 N; noise 0.578 mV = 0.058 N RMS
    f = run(VirtualRig(), np.zeros(20_000), 1000.0)["force_n"]
    steps = np.diff(np.unique(f))
    np.testing.assert_allclose(steps, 20 / 4096 / 0.010003, rtol=1e-9)  # only whole ADC levels
    assert f.mean() == pytest.approx(50.0, abs=0.3)  # the preload, within one level
    fine = VirtualRig(RigConfig().replace(daq={"adc_bits": 24}))
    g = run(fine, np.zeros(20_000), 1000.0)["force_n"]
    # 20,000 samples estimate a standard deviation to about 1 %; allow 3 %
    assert g.std() == pytest.approx(0.000578 / 0.010003, rel=0.03)


def test_mode_frequency_and_damping_from_ringing():
    # Without hysteresis, creep or low-pass, a 20 V step rings at wd = wn sqrt(1 - z^2);
    # the logarithmic decrement of successive peaks gives the damping.
    cfg = RigConfig.clean().replace(
        hysteresis={"enabled": False},
        creep={"enabled": False},
        load_cell={"noise_v": 0.0, "lowpass_hz": 1e7},
        daq={"adc_bits": 24},
    )
    fs = 100_000.0
    v = np.r_[np.zeros(100), np.full(3000, 20.0)]
    f = run(VirtualRig(cfg), v, fs)["force_n"][100:] - (50 + 40)
    peaks, _ = signal.find_peaks(f)
    period = np.mean(np.diff(peaks[:5])) / fs
    wd = 2 * np.pi / period
    z = 0.115
    assert wd == pytest.approx(6440 * np.sqrt(1 - z * z), rel=0.02)  # peak spacing resolved to 1e-5 s
    delta = np.log(f[peaks[0]] / f[peaks[1]])
    assert delta / np.sqrt(4 * np.pi**2 + delta**2) == pytest.approx(z, rel=0.03)


def test_hysteresis_is_asymmetric_and_saturating():
    cfg = RigConfig().hysteresis
    v = np.r_[np.linspace(0, 150, 1501), np.linspace(150, 0, 1501)[1:]]
    h, _ = phys.hysteresis(v, cfg, 150.0)
    up, down = h[:1501], h[1500:][::-1]
    gap = down - up
    assert gap.max() > 0.03 * (h.max() - h.min())  # a real loop
    assert np.all(gap >= -1e-9)  # descending branch above ascending (counter-clockwise loop)
    slope = np.gradient(up, v[:1501])
    assert slope[-10:].mean() < slope[500:600].mean()  # flattens at the top: saturation
    i = np.argmax(gap)
    assert abs(v[i] - 75) > 5  # largest gap off the middle: an asymmetric loop


def test_creep_grows_during_hold():
    rig = VirtualRig(RigConfig().replace(load_cell={"noise_v": 0.0}, interference={"enabled": False}))
    fs = 100.0
    v = np.r_[np.zeros(100), np.full(120 * 100, 150.0)]
    f = run(rig, v, fs)["force_n"]
    f1 = f[100 + 100 - 5 : 100 + 100 + 5].mean()
    f_end = f[-10:].mean()
    assert 0.01 < (f_end - f1) / (f1 - 50.0) < 0.04  # a few percent over two decades of time


def test_amplifier_output_is_limited():
    cfg = RigConfig().replace(amplifier={"output_max_v": 150.0}, actuator={"drive_max_v": 150.0})
    m = run(VirtualRig(cfg), np.full(100, 150.0), 1000.0)
    assert m["monitor_v"].max() <= 150.0


def test_backend_rejects_out_of_range_drive():
    with pytest.raises(BackendError, match="outside the actuator's range -30 to 150 V"):
        run(VirtualRig(), np.full(10, 151.0), 1000.0)


def test_config_errors_name_every_key():
    with pytest.raises(ConfigError) as err:
        parse_rig(
            {"mode": {"damping": -1.0, "colour": 3}, "amplifier": {"gain": "high"}, "tables": {}}, source="rig.toml"
        )
    text = str(err.value)
    assert text.startswith("rig.toml: 4 problem(s)")
    assert "[mode] damping = -1.0: outside the allowed range (0, 2]" in text
    assert "[mode] unknown key 'colour'" in text
    assert "[amplifier] gain = 'high': expected float" in text
    assert "unknown section [tables]" in text
