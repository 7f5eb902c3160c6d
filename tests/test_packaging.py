"""The package as a user installs it: a wheel built from the repository carries the cluster's
plan, and `mirrorcoach up` runs from it outside any checkout; services whose optional
dependency is missing are left out with a word, commands that need one say which extra."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
import typer

from shared.bus.cluster import left_out, load_plan

REPO = Path(__file__).resolve().parent.parent


def test_a_service_whose_dependency_is_missing_is_left_out_and_named(tmp_path):
    plan = tmp_path / "cluster.toml"
    plan.write_text('[router]\nmodule = "shared.bus.router"\n\n[[service]]\nname = "pss"\nmodule = "services.pss"\n\n'
                    '[[service]]\nname = "viewer"\nmodule = "services.observer"\nneeds = "no_such_module_here"\n'
                    'extra = "dashboard"\n')
    assert [p.name for p in load_plan(plan)] == ["router", "pss"]
    assert left_out(plan) == ["viewer is not started: it needs no_such_module_here "
                              "(pip install 'mirrorcoach[dashboard]')"]
    assert "observer" in [p.name for p in load_plan()] and left_out() == []  # here every extra is installed


def test_a_command_that_needs_an_extra_says_which(capsys):
    from shared.cli.common import need

    need("json", "reports", "this")  # installed: nothing happens
    with pytest.raises(typer.Exit) as e:
        need("no_such_module_here", "reports", "study report (its plots)")
    assert e.value.exit_code == 2
    assert "pip install 'mirrorcoach[reports]'" in capsys.readouterr().err


@pytest.mark.slow
def test_mirrorcoach_up_runs_from_a_built_wheel_outside_the_checkout(tmp_path):
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path / "dist"), str(REPO)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    wheel = next((tmp_path / "dist").glob("mirrorcoach-*.whl"))
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
        assert "shared/bus/cluster.toml" in names
        z.extractall(tmp_path / "site")
    away = tmp_path / "elsewhere"
    away.mkdir()
    env = {**os.environ, "PYTHONPATH": str(tmp_path / "site"), "MIRRORCOACH_HOME": str(tmp_path / "home")}
    env.pop("MIRRORCOACH_ROUTER", None)

    def cli(*args, timeout=120):
        return subprocess.run([sys.executable, "-m", "shared.cli", *args], cwd=away, env=env, capture_output=True,
                              text=True, timeout=timeout)

    where = subprocess.run([sys.executable, "-c", "import shared.bus.cluster as c, services.pss as s; "
                            "print(c.PLAN); print(s.__file__)"], cwd=away, env=env, capture_output=True, text=True)
    assert where.returncode == 0, where.stderr
    assert all(line.startswith(str(tmp_path / "site")) for line in where.stdout.split()), where.stdout
    try:
        up = cli("up", timeout=180)
        assert up.returncode == 0, up.stdout + up.stderr
        assert "cluster up" in up.stdout
        status = cli("status")
        assert status.returncode == 0, status.stdout + status.stderr
        assert all(p.name in status.stdout for p in load_plan())
    finally:
        down = cli("down", timeout=120)
    assert down.returncode == 0, down.stdout + down.stderr
