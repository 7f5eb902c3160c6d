"""Contract of the dialogue service (``services/dialogue``): questions to an other, answers
parsed into symbols, transcripts.

Keys: ``<prefix>/dialogue/<verb>``; every transcript line is published on
``<prefix>/events/dialogue/transcript``.
"""

from __future__ import annotations

from schemas.base import Bool, Endpoint, F, Float, Int, List, Map, Message, Str
from schemas.common import CLIP, name

SERVICE = "dialogue"
DIALOGUE = name("dialogue id (one conversation with one other)")
OTHER = name("the other agent (simulated or a person)")

LINE = Map({
    "t": F(Float(0.0), "unix time"),
    "dialogue": DIALOGUE,
    "speaker": F(Str(max_len=64), "'self' or the other's name"),
    "kind": F(Str(choices=("question", "answer", "note")), "what the line is"),
    "text": F(Str(max_len=1000), "the words"),
    "k": F(Int(1, 8), "the answer's symbol index (open questions)", required=False),
    "answer": F(Str(max_len=16), "the parsed comparison (comparative questions)", required=False),
    "understood": F(Bool(), "whether the answer parsed", required=False),
    "dont_know": F(Bool(), "the other said it does not know (understood; no k)", required=False),
})

ASK_OPEN = Endpoint(
    "ask_open",
    Message("dialogue.ask_open", Map({
        "dialogue": DIALOGUE, "other": OTHER,
        "d": F(Int(2, 8), "density of the words (2, 4, 5, 6, 7, 8)", required=False, default=4),
        "clip": F(CLIP, "the shared motion the other performs"),
        "timeout": F(Float(1.0, 3600.0), "seconds to wait for the answer", required=False, default=120.0),
    })),
    Message("dialogue.ask_open.reply", Map({
        "dialogue": DIALOGUE, "question": F(Str(max_len=500)),
        "understood": F(Bool(), "false when the answer is not one of the words"),
        "raw": F(Str(max_len=500), "the answer as given"),
        "word": F(Str(max_len=64), "the parsed word", required=False),
        "k": F(Int(1, 8), "its symbol index k (1 = lightest)", required=False),
        "problem": F(Str(max_len=500), "why it was not understood", required=False),
        "dont_know": F(Bool(), "the other said it does not know (understood; no word, no k)", required=False,
                       default=False),
    })),
    "Ask how heavy a motion felt; parse the word into k (Table 3.1).",
    waits=True,
)

ASK_COMPARE = Endpoint(
    "ask_compare",
    Message("dialogue.ask_compare", Map({
        "dialogue": DIALOGUE, "other": OTHER,
        "clips": F(List(CLIP, min_len=2, max_len=2), "the first and the second motion"),
        "timeout": F(Float(1.0, 3600.0), required=False, default=120.0),
    })),
    Message("dialogue.ask_compare.reply", Map({
        "dialogue": DIALOGUE, "question": F(Str(max_len=500)),
        "understood": F(Bool()), "raw": F(Str(max_len=500)),
        "answer": F(Str(choices=(">", "<", "equal")), "'>' the first felt heavier", required=False),
        "problem": F(Str(max_len=500), required=False),
    })),
    "Ask which of two motions felt heavier (eq. 3.11-3.12).",
    waits=True,
)

TRANSCRIPT = Endpoint(
    "transcript",
    Message("dialogue.transcript", Map({"dialogue": DIALOGUE})),
    Message("dialogue.transcript.reply", Map({
        "dialogue": DIALOGUE, "lines": F(List(LINE, max_len=100_000)),
        "damaged": F(Int(0), "lines that could not be read (a write cut short by a kill), left out", required=False,
                     default=0)})),
    "Every line of a dialogue, in order.",
)

WORDS = Endpoint(
    "words",
    Message("dialogue.words", Map({"d": F(Int(2, 8), "density")})),
    Message("dialogue.words.reply", Map({"d": F(Int(2, 8)), "words": F(List(Str(max_len=64), max_len=8))})),
    "The words of density d, lightest first (Table 3.1).",
)

LIST = Endpoint(
    "list",
    Message("dialogue.list", Map({})),
    Message("dialogue.list.reply", Map({"dialogues": F(List(Map({"dialogue": DIALOGUE, "lines": F(Int(0))}),
                                                             max_len=100_000))})),
    "Every dialogue and its number of lines.",
)

ENDPOINTS = {e.verb: e for e in (ASK_OPEN, ASK_COMPARE, TRANSCRIPT, WORDS, LIST)}
EVENTS = {"transcript": Message("dialogue.event.transcript", LINE, doc="every transcript line as it is written")}
