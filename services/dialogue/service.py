"""The dialogue service: asks an other (through the simulator, whoever sits there) and turns
answers into symbols (contract: ``schemas/dialogue.py``).

Wording, parsing and the symbol tables are ``shared.estimation.symbols``; transcripts are JSON lines in
``$MIRRORCOACH_HOME/data/dialogue/<dialogue>.jsonl`` (a question with its answer appended all
or nothing and fsynced; what a full disk cut short is removed), each line also published as an
event.
"""

from __future__ import annotations

import json
import threading
import time

from schemas import dialogue as contract
from shared.bus.client import RemoteError
from shared.bus.config import Settings
from shared.bus.runtime import Service
from shared.errors import BadInput, MirrorcoachError, NotFound
from shared.estimation.symbols import DONT_KNOW, WORDS, index_of, parse_answer
from shared.io.atomic import append_line, read_lines

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

    def write(*lines: dict) -> None:
        """Append a question and its answer (or note) together, all or nothing: a full disk leaves
        neither half a line nor a question without its answer."""
        lines = [{"t": time.time(), **x} for x in lines]  # a line that carries its own time keeps it
        for x in lines:
            contract.EVENTS["transcript"].validate(x)
        with lock:
            append_line(root / f"{lines[0]['dialogue']}.jsonl", "\n".join(json.dumps(x) for x in lines))
        for x in lines:
            svc.publish("transcript", x)

    def ask(req, kind: str, question: str, clips: list, d: int) -> tuple[dict, str, str | None, str | None]:
        asked = {"t": time.time(), "dialogue": req["dialogue"], "speaker": "self", "kind": "question", "text": question}
        try:
            r = bus().request("simulator", "other_ask", {"other": req["other"], "kind": kind, "clips": clips,
                                                         "text": question, "timeout": req["timeout"]},
                              timeout=req["timeout"] + 30)
        except MirrorcoachError as e:
            if isinstance(e, RemoteError) and e.code in REFUSED:  # never put (no such other, a bad clip): no line
                raise
            # put and not answered (timeout, the simulator down): the transcript says so
            write(asked, {"dialogue": req["dialogue"], "speaker": "self", "kind": "note", "text": f"no answer: {e.message}"})
            raise
        raw = r["answer"]
        try:
            return asked, raw, parse_answer(raw, kind, d), None
        except BadInput as e:
            return asked, raw, None, e.message

    @svc.handler("ask_open")
    def ask_open(req):
        if req["d"] not in WORDS:
            raise BadInput(f"density d must be one of {sorted(WORDS)}, got {req['d']}", field="d")
        asked, raw, word, problem = ask(req, "open", OPEN_QUESTION, [req["clip"]], req["d"])
        unsure = word == DONT_KNOW  # understood, and no word: the question is simply not answered
        k = None if word is None or unsure else index_of(word, req["d"])
        write(asked, {"dialogue": req["dialogue"], "speaker": req["other"], "kind": "answer", "text": raw,
               "understood": word is not None, **({"k": k} if k else {}), **({"dont_know": True} if unsure else {})})
        return {"dialogue": req["dialogue"], "question": OPEN_QUESTION, "understood": word is not None, "raw": raw,
                "word": word, "k": k, "problem": problem, "dont_know": unsure}

    @svc.handler("ask_compare")
    def ask_compare(req):
        asked, raw, answer, problem = ask(req, "compare", COMPARE_QUESTION, req["clips"], 4)
        write(asked, {"dialogue": req["dialogue"], "speaker": req["other"], "kind": "answer", "text": raw,
               "understood": answer is not None, **({"answer": answer} if answer else {})})
        return {"dialogue": req["dialogue"], "question": COMPARE_QUESTION, "understood": answer is not None,
                "raw": raw, "answer": answer, "problem": problem}

    @svc.handler("transcript")
    def transcript(req):
        p = root / f"{req['dialogue']}.jsonl"
        if not p.exists():
            raise NotFound(f"no dialogue {req['dialogue']!r}", dialogue=req["dialogue"])
        with lock:
            raw, damaged = read_lines(p)
        lines = []
        for x in raw:  # a line that cannot be read (an older version's torn write) is counted, never fatal
            try:
                lines.append(contract.EVENTS["transcript"].validate(json.loads(x)))
            except (ValueError, BadInput):
                damaged += 1
        return {"dialogue": req["dialogue"], "lines": lines, "damaged": damaged}

    @svc.handler("words")
    def words(req):
        if req["d"] not in WORDS:
            raise BadInput(f"density d must be one of {sorted(WORDS)}, got {req['d']}", field="d")
        return {"d": req["d"], "words": list(WORDS[req["d"]])}

    @svc.handler("list")
    def list_dialogues(req):
        with lock:
            return {"dialogues": [{"dialogue": p.stem, "lines": len(read_lines(p)[0])}
                                  for p in sorted(root.glob("*.jsonl"))]}

    return svc
