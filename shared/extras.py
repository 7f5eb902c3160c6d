"""The optional parts of mirrorcoach (pyproject.toml's extras) and the one line that says how to
install one that is missing. The supervisor leaves out a service whose extra is missing; the
command line turns a missing extra's import into that line instead of a traceback."""

from __future__ import annotations

import importlib.util

#: the top-level module of each optional dependency -> the extra that installs it
EXTRAS = {"rerun": "dashboard", "rerun_cli": "dashboard", "matplotlib": "reports", "cryptography": "deploy"}


def install_hint(module: str) -> str:
    root = module.split(".")[0]
    return f"{root} is not installed: pip install 'mirrorcoach[{EXTRAS.get(root, root)}]'"


def missing(module: str) -> str | None:
    """None when ``module`` can be imported, else :func:`install_hint`'s line."""
    try:
        found = importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        found = False
    return None if found else install_hint(module)


def hint_for(error: ModuleNotFoundError) -> str | None:
    """The install line for an import that failed on an optional dependency, else None."""
    root = (error.name or "").split(".")[0]
    return install_hint(root) if root in EXTRAS else None
