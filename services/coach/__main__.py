"""``python -m services.coach``: run the coach service until SIGTERM."""

from services.runner import main

if __name__ == "__main__":
    raise SystemExit(main("coach", "services.coach.service"))
