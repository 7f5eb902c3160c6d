"""The package as a user installs it: a wheel built from the repository carries the cluster's
plan, and `mirrorcoach up` runs from it outside any checkout; services whose optional
dependency is missing are left out with a word, commands that need one say which extra."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
import typer

from shared.bus.cluster import load_plan, plan_with_left_out
from shared.extras import install_hint

REPO = Path(__file__).resolve().parent.parent


def test_a_service_whose_dependency_is_missing_is_left_out_and_named(tmp_path):
    plan = tmp_path / "cluster.toml"
    plan.write_text('[router]\nmodule = "shared.bus.router"\n\n[[service]]\nname = "pss"\nmodule = "services.pss"\n\n'
                    '[[service]]\nname = "viewer"\nmodule = "services.observer"\nneeds = "no_such_module_here"\n')
    procs, left = plan_with_left_out(plan)
    assert [p.name for p in procs] == ["router", "pss"] and [p.name for p in load_plan(plan)] == ["router", "pss"]
    assert left == ["viewer is not started: no_such_module_here is not installed: "
                    "pip install 'mirrorcoach[no_such_module_here]'"]
    assert install_hint("matplotlib.pyplot") == "matplotlib is not installed: pip install 'mirrorcoach[reports]'"
    procs, left = plan_with_left_out()  # here every extra is installed
    assert "observer" in [p.name for p in procs] and left == []


def test_a_command_whose_extra_is_missing_says_which_in_one_line(tmp_path, capsys):
    """Any command: the import of a missing extra becomes one line and exit 2 (deploy init here,
    cryptography hidden from the process); a long run checks before it starts."""
    from shared.cli.common import need

    hide = ("import sys\n"
            "class Hidden:\n"
            "    def find_spec(self, name, path=None, target=None):\n"
            "        if name.split('.')[0] == 'cryptography':\n"
            "            raise ModuleNotFoundError(f'No module named {name!r}', name=name)\n"
            "sys.meta_path.insert(0, Hidden())\n"
            f"sys.argv = ['mirrorcoach', 'deploy', 'init', {str(tmp_path / 'dep')!r}, '--router', 'r1=10.0.0.1']\n"
            "from shared.cli.entry import main\n"
            "main()\n")
    r = subprocess.run([sys.executable, "-c", hide], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert r.stderr.strip() == "error: cryptography is not installed: pip install 'mirrorcoach[deploy]'"
    need("json", "this")  # installed: nothing happens
    with pytest.raises(typer.Exit) as e:
        need("no_such_module_here", "reproduce (its plots at the end of the run)")
    assert e.value.exit_code == 2 and "needs no_such_module_here is not installed" in capsys.readouterr().err


@pytest.mark.slow
def test_mirrorcoach_up_runs_from_a_built_wheel_outside_the_checkout(tmp_path):
    # built from a copy: setuptools writes build/ and *.egg-info beside the sources, and a stale
    # build/ in the checkout would put modules that no longer exist into the wheel
    src = tmp_path / "src"
    shutil.copytree(REPO, src, ignore=shutil.ignore_patterns(".git", ".venv", "build", "var", "out", "*.egg-info",
                                                             "__pycache__", ".*_cache", "reports", "docs"))
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path / "dist"), str(src)],
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
