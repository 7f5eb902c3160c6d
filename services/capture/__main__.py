"""``python -m services.capture``: run the capture service until SIGTERM."""

from services.runner import main

if __name__ == "__main__":
    raise SystemExit(main("capture", "services.capture.service"))
