"""``python -m services.pss``: run the PSS model service until SIGTERM."""

from services.runner import main

if __name__ == "__main__":
    raise SystemExit(main("pss", "services.pss.service"))
