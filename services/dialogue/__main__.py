"""``python -m services.dialogue``: run the dialogue service until SIGTERM."""

from services.runner import main

if __name__ == "__main__":
    raise SystemExit(main("dialogue", "services.dialogue.service"))
