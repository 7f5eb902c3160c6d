"""The dialogue service: asks an other (through the simulator, whoever sits there) and turns
answers into symbols (contract: ``schemas/dialogue.py``).

Wording, parsing and the symbol tables are ``shared.symbols``; transcripts are JSON lines in
``$MIRRORCOACH_HOME/data/dialogue/<dialogue>.jsonl`` (appended and fsynced line by line), each
line also published as an event.
"""

from __future__ import annotations

import json
import os
import threading
import time

from schemas import dialogue as contract
from shared.bus.client import RemoteError
from shared.bus.config import Settings
from shared.bus.runtime import Service
from shared.errors import BadInput, MirrorcoachError, NotFound
from shared.symbols import WORDS, index_of, parse_answer

#: the simulator's refusals: the question was never put to the other
REFUSED = ("bad_request", "not_found", "conflict")

OPEN_QUESTION = "How heavy did that feel?"
COMPARE_QUESTION = "Which felt heavier, the first or the second?"


def make_service(settings: Settings | None = None) -> Service:
    settings = settings or Settings()
    root = settings.data_dir("dialogue")
    root.mkdir(parents=True, exist_ok=True)
    svc = Service(contract.SERVICE, contract.ENDPOINTS, contract.EVENTS, settings=settings)
    lock = threading.Lock()
    bus = svc.client

    def write(line: dict) -> dict:
        line = {"t": time.time(), **line}  # a line that carries its own time keeps it
        contract.EVENTS["transcript"].validate(line)
        with lock, open(root / f"{line['dialogue']}.jsonl", "a") as f:
            f.write(json.dumps(line) + "\n")
            f.flush()
            os.fsync(f.fileno())
        svc.publish("transcript", line)
        return line

    def ask(req, kind: str, question: str, clips: list, d: int) -> tuple[str, str | None, str | None]:
        asked = {"t": time.time(), "dialogue": req["dialogue"], "speaker": "self", "kind": "question", "text": question}
        try:
            r = bus().request("simulator", "other_ask", {"other": req["other"], "kind": kind, "clips": clips,
                                                         "text": question, "timeout": req["timeout"]},
                              timeout=req["timeout"] + 30)
        except MirrorcoachError as e:
            if isinstance(e, RemoteError) and e.code in REFUSED:  # never put (no such other, a bad clip): no line
                raise
            write(asked)  # put and not answered (timeout, the simulator down): the transcript says so
            write({"dialogue": req["dialogue"], "speaker": "self", "kind": "note", "text": f"no answer: {e.message}"})
            raise
        write(asked)
        raw = r["answer"]
        try:
            return raw, parse_answer(raw, kind, d), None
        except BadInput as e:
            return raw, None, e.message

    @svc.handler("ask_open")
    def ask_open(req):
        if req["d"] not in WORDS:
            raise BadInput(f"density d must be one of {sorted(WORDS)}, got {req['d']}", field="d")
        raw, word, problem = ask(req, "open", OPEN_QUESTION, [req["clip"]], req["d"])
        k = None if word is None else index_of(word, req["d"])
        write({"dialogue": req["dialogue"], "speaker": req["other"], "kind": "answer", "text": raw,
               "understood": word is not None, **({"k": k} if k else {})})
        return {"dialogue": req["dialogue"], "question": OPEN_QUESTION, "understood": word is not None, "raw": raw,
                "word": word, "k": k, "problem": problem}

    @svc.handler("ask_compare")
    def ask_compare(req):
        raw, answer, problem = ask(req, "compare", COMPARE_QUESTION, req["clips"], 4)
        write({"dialogue": req["dialogue"], "speaker": req["other"], "kind": "answer", "text": raw,
               "understood": answer is not None, **({"answer": answer} if answer else {})})
        return {"dialogue": req["dialogue"], "question": COMPARE_QUESTION, "understood": answer is not None,
                "raw": raw, "answer": answer, "problem": problem}

    @svc.handler("transcript")
    def transcript(req):
        p = root / f"{req['dialogue']}.jsonl"
        if not p.exists():
            raise NotFound(f"no dialogue {req['dialogue']!r}", dialogue=req["dialogue"])
        with lock:
            lines = [json.loads(x) for x in p.read_text().splitlines() if x.strip()]
        return {"dialogue": req["dialogue"], "lines": lines}

    @svc.handler("words")
    def words(req):
        if req["d"] not in WORDS:
            raise BadInput(f"density d must be one of {sorted(WORDS)}, got {req['d']}", field="d")
        return {"d": req["d"], "words": list(WORDS[req["d"]])}

    @svc.handler("list")
    def list_dialogues(req):
        with lock:
            return {"dialogues": [{"dialogue": p.stem, "lines": sum(1 for _ in open(p))}
                                  for p in sorted(root.glob("*.jsonl"))]}

    return svc
