"""``python -m services.estimator``: run the estimator service until SIGTERM."""

from services.runner import main

if __name__ == "__main__":
    raise SystemExit(main("estimator", "services.estimator.service"))
