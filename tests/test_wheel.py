"""The installed package (issue 12): the wheel built from this tree, installed into a fresh
virtual environment outside the checkout, runs characterize -> fit -> validate -> report.

Slow (it builds a wheel); CI runs it (`.ci/run`). The fresh environment gets the project's
dependencies from the running environment through a path file, so nothing is downloaded
but the build backend.
"""

import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(args, cwd, env=None):
    res = subprocess.run([str(a) for a in args], cwd=cwd, env=env, capture_output=True, text=True)
    assert res.returncode == 0, f"{' '.join(map(str, args))}\n{res.stdout[-3000:]}\n{res.stderr[-3000:]}"
    return res.stdout


@pytest.mark.slow
def test_the_wheel_installs_and_runs_outside_the_checkout(tmp_path):
    # built from a copy of the tree, so the build leaves nothing (build/, *.egg-info) in the checkout
    src = tmp_path / "src"
    shutil.copytree(
        ROOT,
        src,
        ignore=shutil.ignore_patterns(
            ".venv",
            ".git",
            "out",
            "build",
            "report",
            "*.egg-info",
            "__pycache__",
            ".pytest_cache",
            ".hypothesis",
            "sample_runs",
        ),
    )
    dist = tmp_path / "dist"
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", dist, src], cwd=tmp_path)
    (wheel,) = dist.glob("piezopress-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    # only the project's own name at the top level; the plans and rig files inside the package
    assert {n.split("/")[0] for n in names} == {
        "piezopress",
        wheel.name.split("-py3")[0].replace("-", "-", 1) + ".dist-info",
    }
    assert "piezopress/protocols/characterize.toml" in names and "piezopress/rigs/thesis-press.toml" in names
    assert "piezopress/piezocli/main.py" in names and "piezopress/pipelines/fit.py" in names

    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", venv], cwd=tmp_path)
    bindir = venv / ("Scripts" if os.name == "nt" else "bin")
    py = next(bindir.glob("python*"))
    purelib = _run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], cwd=tmp_path).strip()
    Path(purelib, "_piezopress_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")  # numpy, scipy, ... only
    _run([sys.executable, "-m", "pip", "--python", py, "install", "--no-deps", "-q", wheel], cwd=tmp_path)

    work = tmp_path / "work"  # outside the checkout: nothing of the tree is reachable
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    exe = bindir / "piezopress"
    where = _run([py, "-c", "import piezopress.pipelines.fit as f; print(f.__file__)"], cwd=work, env=env)
    assert Path(where.strip()).is_relative_to(venv)
    _run([exe, "characterize", "--out", "char"], cwd=work, env=env)
    _run([exe, "fit", "char", "--out", "bundle.json"], cwd=work, env=env)
    _run([exe, "validate", "--bundle", "bundle.json", "--out", "val"], cwd=work, env=env)
    out = _run(
        [
            exe,
            "report",
            "--characterization",
            "char",
            "--validation",
            "val",
            "--bundle",
            "bundle.json",
            "--out",
            "report",
        ],
        cwd=work,
        env=env,
    )
    assert (work / "report" / "report.html").is_file() and "Report:" in out
    _run([exe, "protocols", "--copy", "plans"], cwd=work, env=env)
    assert (work / "plans" / "characterize.toml").read_text() == (ROOT / "protocols" / "characterize.toml").read_text()
    _run([exe, "rig-keys", "--template", "my-rig.toml"], cwd=work, env=env)
    _run([exe, "check-rig", "--rig", "my-rig.toml"], cwd=work, env=env)
