"""``python -m services.simulator``: run the simulator service until SIGTERM."""

from services.runner import main

if __name__ == "__main__":
    raise SystemExit(main("simulator", "services.simulator.service"))
