"""Text condition alignment (TCA, the paper's section 2.3): free-form prompts rewritten into the training captions' style.

A model conditions best on prompts that look like what it was trained on ("a person jumps in place twice."),
not on "yo make the dude do a lil hop". The paper rewrites prompts with a large language model; a game on an
edge device has none, so the default here is offline and ships inside the bundle:

    from mogo_runtime.tca import OfflineAligner, ChatRewriter
    aligner = OfflineAligner(bundle, text_session)          # bundle has captions.npz (manifest section "tca")
    aligned = aligner.align("guy starts jogging real quick, then sits")
    aligned.text        # e.g. 'a person jogs forward slowly and then sits down.' (see `method`)
    aligned.embedding   # None, or an embedding to condition on instead of encoding `text` (method "blend")

`OfflineAligner` (1) normalises the wording: lowercase, emojis to words, filler / slang / politeness dropped, the
subject made "a person", causatives ("make him ...") and auxiliaries ("is gonna start ...") removed, verbs put in
the present tense and mapped to the caption vocabulary (a synonym table applied only where the caption index
lacks the word), objects the captions never mention dropped; (2) splits compound requests into ordered clauses
("X and then Y", "then", "after that", "X before Y", "X after Y", commas; a bare "and" only where retrieval says
the parts match the captions better than the whole); (3) retrieves the nearest training captions by cosine
similarity of text embeddings against the bundle's caption index, re-ranked by agreement on direction words
(left/right, forward/backward), and (4) conditions on one of:
  - "normalize": the normalised sentence itself (no retrieval),
  - "nearest":   the nearest training caption per clause, clauses joined HumanML3D-style "a person X and then Y",
  - "blend":     a similarity-weighted mean of the top-k caption embeddings (single clause; else "nearest").
The bundle's manifest names the default (`tca.method`, chosen by measurement, see docs/tca.md).

`ChatRewriter` calls an OpenAI-compatible /v1/chat/completions endpoint with a style prompt built from a few
training captions; any failure (timeout, HTTP error, malformed reply) warns and falls back to the offline path.

No caption index in the bundle: `OfflineAligner` still normalises and splits the wording (method "normalize")
and warns once that retrieval is unavailable.
"""
from __future__ import annotations

import json
import os
import re
import unicodedata
import warnings
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

INDEX_FORMAT = "mogo-caption-index"
INDEX_VERSION = 1
METHODS = ("normalize", "nearest", "blend")
DEFAULTS = {"method": "nearest", "top_k": 8, "temperature": 0.05, "lexical_weight": 0.05, "split_margin": 0.02}


# --------------------------------------------------------------------------------------------- the result

@dataclass
class AlignedPrompt:
    """What the model is conditioned on for one prompt.

    text: the aligned prompt (shown to the user, returned as `Motion.aligned_text`); embedding: when not None,
    the (text_dim,) float32 embedding to condition on instead of encoding `text`; method: how it was made
    ("none", "normalize", "nearest", "blend", "chat"); details: the intermediate steps (clauses, neighbours
    and their similarities, fallback reason ...) for inspection and logs.
    """
    text: str
    embedding: np.ndarray | None
    method: str
    details: dict = field(default_factory=dict)


class Aligner(ABC):
    """Raw prompt -> AlignedPrompt. Implementations never raise on odd wording; they return their best try."""

    @abstractmethod
    def align(self, text: str) -> AlignedPrompt:
        ...

    def align_batch(self, texts: list[str]) -> list[AlignedPrompt]:
        return [self.align(t) for t in texts]


# --------------------------------------------------------------------------------------------- the index

def quantize_rows(x: np.ndarray, dtype: str = "int8") -> tuple[np.ndarray, np.ndarray | None]:
    """(N, D) float -> stored rows: int8 with a per-row scale (symmetric, max |x| -> 127), or float16 (scale None)."""
    x = np.asarray(x, np.float32)
    if dtype == "float16":
        return x.astype(np.float16), None
    if dtype != "int8":
        raise ValueError(f"caption index dtype must be 'int8' or 'float16', got {dtype!r}")
    scale = np.abs(x).max(axis=1) / 127.0
    scale = np.where(scale > 0, scale, 1.0).astype(np.float32)
    q = np.clip(np.rint(x / scale[:, None]), -127, 127).astype(np.int8)
    return q, scale


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), 1e-12)


@dataclass
class CaptionIndex:
    """Training captions and their unit embeddings (float32 in memory; int8 + per-row scale or float16 on disk)."""
    captions: list[str]
    embeddings: np.ndarray              # (N, dim) float32, unit rows
    labels: list[str] | None = None     # action family per caption ("seq:a+b" for two-action clips), if known
    encoder: str = ""
    dtype: str = "float32"

    def __post_init__(self):
        self.embeddings = _unit(np.asarray(self.embeddings, np.float32))
        if self.embeddings.ndim != 2 or len(self.embeddings) != len(self.captions):
            raise ValueError(f"caption index: {len(self.captions)} captions but embeddings of shape "
                             f"{self.embeddings.shape}")
        if self.labels is not None and len(self.labels) != len(self.captions):
            raise ValueError(f"caption index: {len(self.labels)} labels for {len(self.captions)} captions")

    def __len__(self) -> int:
        return len(self.captions)

    @property
    def dim(self) -> int:
        return int(self.embeddings.shape[1])

    def save(self, path: str | Path, dtype: str = "int8") -> dict:
        """Write `path` (.npz, no pickles); -> the facts a manifest records about it."""
        path = Path(path)
        rows, scale = quantize_rows(self.embeddings, dtype)
        arrays = {"format": np.array(INDEX_FORMAT), "version": np.array(INDEX_VERSION, np.int64),
                  "encoder": np.array(self.encoder), "captions": np.array(self.captions, dtype=np.str_),
                  "embeddings": rows}
        if scale is not None:
            arrays["scales"] = scale
        if self.labels is not None:
            arrays["labels"] = np.array([lb or "" for lb in self.labels], dtype=np.str_)
        with open(path, "wb") as f:
            np.savez_compressed(f, **arrays)
        return {"file": path.name, "count": len(self), "dim": self.dim, "dtype": dtype, "encoder": self.encoder,
                "labels": self.labels is not None}

    @classmethod
    def load(cls, path: str | Path) -> "CaptionIndex":
        path = Path(path)
        try:
            z = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as e:
            raise ValueError(f"{path}: not a readable caption index ({e})") from None
        with z:
            if "format" not in z.files or str(z["format"]) != INDEX_FORMAT:
                raise ValueError(f"{path}: not a {INDEX_FORMAT} file (arrays: {sorted(z.files)})")
            if int(z["version"]) != INDEX_VERSION:
                raise ValueError(f"{path}: caption index version {int(z['version'])}, this runtime reads "
                                 f"{INDEX_VERSION}")
            rows = z["embeddings"]
            if rows.dtype == np.int8:
                if "scales" not in z.files:
                    raise ValueError(f"{path}: int8 embeddings without 'scales'")
                emb, dtype = rows.astype(np.float32) * z["scales"][:, None], "int8"
            elif rows.dtype == np.float16:
                emb, dtype = rows.astype(np.float32), "float16"
            else:
                emb, dtype = rows.astype(np.float32), str(rows.dtype)
            labels = [lb or None for lb in z["labels"].tolist()] if "labels" in z.files else None
            return cls(z["captions"].tolist(), emb, labels, str(z["encoder"]), dtype)

    def search(self, queries: np.ndarray, k: int, mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(Q, dim) queries -> (indices (Q, k), cosine similarities (Q, k)), best first; `mask` (N,) restricts rows."""
        q = _unit(np.atleast_2d(np.asarray(queries, np.float32)))
        if q.shape[1] != self.dim:
            raise ValueError(f"query embeddings have {q.shape[1]} values, the caption index {self.dim}")
        sims = q @ self.embeddings.T                                           # (Q, N)
        if mask is not None:
            sims = np.where(mask[None, :], sims, -np.inf)
        k = min(k, int(mask.sum()) if mask is not None else len(self))
        idx = np.argsort(-sims, axis=1, kind="stable")[:, :k]
        return idx, np.take_along_axis(sims, idx, axis=1)


# ------------------------------------------------------------------------------------ wording normalisation

_EMOJI = {"👋": " wave ", "🏃": " run ", "🚶": " walk ", "👏": " clap ", "🙇": " bow ", "👊": " punch ", "🥊": " punch ",
          "🦵": " kick ", "🪑": " sit down ", "🙌": " raise both arms ", "🕺": " dance ", "💃": " dance ",
          "🤸": " jump ", "⬅️": " left ", "➡️": " right ", "⬅": " left ", "➡": " right "}
_NUMBERS = {"1": "one", "2": "two", "3": "three", "4": "four", "5": "five", "6": "six", "7": "seven", "8": "eight",
            "9": "nine", "10": "ten", "11": "eleven", "12": "twelve"}
_TIMES = {"1": "once", "one": "once", "2": "twice", "two": "twice", "3": "three times", "three": "three times",
          "4": "four times", "four": "four times", "5": "five times", "five": "five times"}
_CONTRACTIONS = [(r"\bgonna\b", "going to"), (r"\bwanna\b", "want to"), (r"\bgotta\b", "got to"),
                 (r"\b(\w+)in'", r"\1ing"), (r"\b(\w+)'(s|re|ll|ve|d|m)\b", r"\1"), (r"n't\b", " not")]

# Who does it: removed at a clause's start, and after causatives ("make the dude ...").
_SUBJECTS = (r"(?:the|a|an|this|that|my|our|your|ur|some|one)?\s*(?:little\s+|lil\s+|old\s+|big\s+|young\s+)?"
             r"(?:person|persons|people|man|men|woman|women|guy|guys|dude|dudes|girl|boy|kid|child|lady|gentleman|"
             r"character|avatar|player|figure|model|actor|human|individual|fella|fellow|bro|homie|buddy|npc|"
             r"mannequin|robot|skeleton|body|subject|hero)"
             r"|someone|somebody|anyone|he|she|they|him|her|them|it|we|you|ya|u|i|me|us")
_CAUSATIVE = re.compile(rf"\b(?:make|makes|made|making|have|has|had|let|lets|get|gets|got|want|wants|need|needs|"
                        rf"see|show|watch)\s+(?:{_SUBJECTS})\s+(?:to\s+)?")
_LEADING_SUBJECT = re.compile(rf"^(?:{_SUBJECTS})\s+")
# Auxiliaries / aspect verbs before the action verb: dropped when a motion verb follows.
_HELPERS = {"is", "are", "was", "were", "be", "been", "being", "am", "will", "would", "should", "shall", "can",
            "could", "may", "might", "must", "going", "goes", "go", "went", "to", "start", "starts", "started",
            "starting", "begin", "begins", "began", "beginning", "keep", "keeps", "kept", "keeping", "try", "tries",
            "tried", "want", "wants", "wanted", "need", "needs", "needed", "got", "get", "gets", "has", "have",
            "had", "just", "then", "now", "also", "suddenly", "proceeds", "proceed", "decides",
            "decide", "decided", "continue", "continues", "continued", "please", "do", "does", "did", "and",
            "gonna", "wanna", "gotta", "finally", "first", "next", "afterwards", "lastly", "again"}
# Words that carry no motion: dropped anywhere (multi-word fillers first).
_FILLER_PHRASES = [r"\bcan you\b", r"\bcould you\b", r"\bwould you\b", r"\bwill you\b", r"\bi want\b",
                   r"\bi'd like\b", r"\bi would like\b", r"\bi need\b", r"\blet's see\b", r"\blets see\b",
                   r"\bkind of\b", r"\bkinda\b", r"\bsort of\b", r"\bsorta\b", r"\ba bit\b", r"\ba little bit\b",
                   r"\bfor me\b", r"\bfor a bit\b", r"\bfor a while\b", r"\bfor a sec(?:ond)?\b", r"\bright now\b",
                   r"\bor something\b", r"\bor whatever\b", r"\byou know\b", r"\bi guess\b", r"\bi think\b",
                   r"\bif you can\b", r"\bthank you\b", r"\bthanks\b", r"\bhere\b", r"\bthere\b",
                   r"\bon (?:the )?(?:screen|camera)\b", r"\bin the (?:game|scene|animation|video)\b",
                   r"\blike a (?:boss|pro|champ|maniac|madman|crazy person)\b", r"\ball of a sudden\b",
                   r"\bnothing (?:fancy|special|crazy|complicated|else)\b"]
_FILLERS = {"yo", "hey", "ok", "okay", "so", "um", "uh", "umm", "erm", "hmm", "like", "just", "pls", "plz",
            "please", "lol", "lmao", "rofl", "bro", "bruh", "fam", "ngl", "tbh", "fr", "rn", "omg",
            "lil", "little", "some", "really", "real", "super", "totally", "literally", "basically", "actually",
            "very", "pretty", "quite", "kinda", "sorta", "now", "cool", "nice", "awesome", "epic", "dope", "sick",
            "gently", "casually", "happily", "sadly", "angrily", "excitedly", "proudly", "nervously", "lazily",
            "aight", "alright", "well", "hella", "mad", "lowkey", "highkey", "simply", "nicely",
            "tho", "though", "anyway", "anyways", "oh", "wow", "yeah", "yep", "sure"}

# Multi-word rewrites into caption phrasing, applied before verbs are found (base forms; inflected later).
_PHRASES = [
    (r"\bback(?:s|ed|ing)? (?:it )?up\b", "walk backward"), (r"\bbackpedal(?:s|ed|ing|led|ling)?\b", "walk backward"),
    (r"\b(?:go|goes|went|going|move|moves|moved|moving) (?:in reverse|backwards?)\b", "walk backward"),
    (r"\breverse(?:s|d)?\b(?! order)", "walk backward"),
    (r"\b(?:go|goes|went|going|move|moves|moved|moving|head|heads|headed|heading) back\b", "walk backward"),
    (r"\b(?:take|takes|took|taking|have|has|had|grab|grabs|grabbed) a (?:seat|chair|load off)\b", "sit down"),
    (r"\b(?:sit|sits|sat|sitting) (?:his|her|their|your|ur|my) (?:butt|ass|bum|self) down\b", "sit down"),
    (r"\bplop(?:s|ped|ping)?(?: down)?\b", "sit down"), (r"\bbe seated\b", "sit down"),
    (r"\b(?:say|says|said|saying) (?:hi|hello|hey|bye|goodbye|good bye|hiya|howdy)\b", "wave hello"),
    (r"\b(?:give|gives|gave|giving) (?:a |an )?(?:friendly )?(?:wave|hello)\b", "wave"),
    (r"\b(?:throw|throws|threw|throwing) (?:hands|fists|some hands|a few punches|punches|jabs)\b", "punch"),
    (r"\b(?:round of )?applause\b", "clap"), (r"\b(?:give|gives|gave|giving) (?:a )?clap\b", "clap"),
    (r"\b(?:do|does|did|doing|make|makes|made|pull|pulls|pulled|pulling) (?:a |an )?180\b", "turn around"),
    (r"\b(?:do|does|did|doing|make|makes|made|pull|pulls|pulled|pulling) (?:a |an )?360\b", "spin around"),
    (r"\b(?:do|does|did|doing|make|makes|made) (?:a |an )?90\b", "make a quarter turn"),
    (r"\babout[- ]face\b", "turn around"), (r"\bu[- ]?turn\b", "turn around"),
    (r"\b(?:go|goes|went|going|move|moves|moved|moving|run|runs|ran|running) (?:around |round )?in (?:a |one )?"
     r"(?:big |small |large |little |full |wide |tight )?(?:circle|loop|ring)s?\b", "walk in a circle"),
    (r"\b(?:do|does|did|doing|walk|walks|walked|walking) (?:a )?(?:lap|loop)s?\b", "walk in a circle"),
    (r"\bjumping jacks?\b", "jump in place"), (r"\bstar jumps?\b", "jump in place"),
    (r"\b(?:do|does|did|doing|stand|stands|stood|standing) nothing\b", "stand still"),
    (r"\b(?:stay|stays|stayed|staying|stand|stands|stood|standing|wait|waits|waited|waiting|hang|hangs|hung|"
     r"hanging) (?:still|around|there|put|idle|in place)\b", "stand still"),
    (r"\b(?:chill|chills|chilled|chilling|chillin|vibe|vibes|vibed|vibing|idle|idles|idling|loiter|loiters|"
     r"loitering|relax|relaxes|relaxing|wait|waits|waiting|rest|rests|resting|pause|pauses|pausing|freeze|"
     r"freezes|froze|freezing)\b", "stand still"),
    (r"\b(?:put|puts|putting|throw|throws|threw|throwing|stick|sticks|stuck|sticking) (?:his |her |their |your |"
     r"ur |my |both )?(?:hands|arms) (?:up|in the air|up in the air|to the sky)\b", "raise both arms"),
    (r"\b(?:reach|reaches|reached|reaching|stretch|stretches|stretched|stretching) (?:up|upward|upwards|"
     r"(?:up |out )?(?:for|to|towards?) the (?:sky|ceiling|stars|heavens))\b", "raise both arms"),
    (r"^(?:both |his |her |their |your |ur |my |the )?(?:hands|arms) (?:up|in the air|up in the air|up high|"
     r"to the sky|overhead)\b", "raise both arms"),
    (r"\b(?:fist )?pump(?:s|ed|ing)? (?:his |her |their |your |ur |my )?fists?\b", "punch"),
    (r"\b(?:step|steps|stepped|stepping|move|moves|moved|moving|slide|slides|slid|sliding|scoot|scoots|scooted|"
     r"scooting) (?:to the |towards the |toward the |over to the |)(left|right)(?:wards?| side)?\b",
     r"sidestep to the \1"),
    (r"\bside ?step(?:s|ped|ping)?\b", "sidestep"), (r"\bstrafe(?:s|d)?\b|\bstrafing\b", "sidestep"),
    (r"\bcrab[- ]walk(?:s|ed|ing)?\b", "sidestep"),
    (r"\b(?:go|goes|went|going|move|moves|moved|moving|head|heads|headed|heading) (?:straight )?(forwards?|ahead)\b",
     r"walk \1"),
    (r"\b(?:bend|bends|bent|bending) (?:over|at the waist)\b", "bow"),
    (r"\b(?:hit|hits|hitting|drop|drops|dropped|dropping|get|gets|got|getting) (?:down )?(?:low|into a squat)\b",
     "squat down"),
    (r"\bon the spot\b", "in place"), (r"\bin one place\b", "in place"), (r"\bwhere (?:he|she|they|it) (?:is|are|"
     r"stands?)\b", "in place"),
    (r"\bcounter[- ]?clockwise\b", "counterclockwise"), (r"\banti[- ]?clockwise\b", "counterclockwise"),
    (r"\b(?:a )?couple (?:of )?times\b", "twice"), (r"\b(?:a )?few times\b", "three times"),
    (r"\bx ?(\d+)\b", r"\1 times"), (r"\b(\d+) ?x\b", r"\1 times"),
    (r"\bwith (?:his|her|their|your|ur|my|the) (left|right)\b(?! (?:hand|arm|leg|foot|fist|side|shoulder))",
     r"with \1 hand"),
]

# Verbs: base forms a prompt may use, and what they mean in the captions' vocabulary (only where the index
# does not know the word itself). Written as a general lexicon of everyday motion verbs.
_SYNONYMS = {
    "stroll": "walk", "amble": "walk", "saunter": "walk", "stride": "walk", "strut": "walk", "wander": "walk",
    "trudge": "walk", "mosey": "walk", "hike": "walk", "march": "walk", "tread": "walk", "pace": "walk",
    "waddle": "walk", "stomp": "walk", "tiptoe": "walk", "promenade": "walk", "trek": "walk", "advance": "walk",
    "retreat": "walk backward", "recede": "walk backward",
    "jog": "run", "sprint": "run", "dash": "run", "race": "run", "rush": "run", "bolt": "run", "scurry": "run",
    "hustle": "run", "zoom": "run", "gallop": "run", "scamper": "run", "charge": "run", "speed": "run",
    "hop": "jump", "leap": "jump", "bounce": "jump", "spring": "jump", "bound": "jump", "vault": "jump",
    "skip": "jump", "pounce": "jump", "lunge": "jump",
    "greet": "wave", "salute": "wave", "hail": "wave", "beckon": "wave",
    "boot": "kick", "punt": "kick", 
    "crouch": "squat", "kneel": "squat", "duck": "squat", "hunker": "squat", "dip": "squat", "stoop": "squat",
    "rotate": "turn", "pivot": "turn", "spin": "turn", "twirl": "turn", "swivel": "turn", "whirl": "turn",
    "sit": "sit", "perch": "sit", "settle": "sit",
    "hit": "punch", "strike": "punch", "jab": "punch", "box": "punch", "sock": "punch", "smack": "punch",
    "slug": "punch", "pummel": "punch", "spar": "punch", "fight": "punch", "uppercut": "punch", 
    "applaud": "clap", "cheer": "clap",
    "shuffle": "sidestep", "slide": "sidestep", "scoot": "sidestep", "strafe": "sidestep",
    "lift": "raise", "hoist": "raise", "elevate": "raise", "reach": "raise", "hold": "raise",
    "idle": "stand", "wait": "stand", "stay": "stand", "linger": "stand", "loiter": "stand", "chill": "stand",
    "curtsy": "bow", "curtsey": "bow", "nod": "bow",
}
# Nouns after "do/give/throw/take a ...": the verb they stand for.
_NOUN_VERBS = {"hop": "hop", "jump": "jump", "leap": "leap", "kick": "kick", "squat": "squat", "wave": "wave",
               "bow": "bow", "punch": "punch", "jab": "jab", "clap": "clap", "spin": "spin", "twirl": "spin",
               "sprint": "sprint", "jog": "jog", "run": "run", "walk": "walk", "stroll": "walk", "curtsy": "bow",
               "sidestep": "sidestep", "turn": "turn", "uppercut": "punch", "hook": "punch", "squats": "squat",
               "kicks": "kick", "jumps": "jump", "hops": "hop", "punches": "punch", "bows": "bow", "claps": "clap",
               "leaps": "leap", "spins": "spin", "waves": "wave", "jabs": "jab", "lunge": "lunge", "lunges": "lunge"}
_IRREGULAR = {"ran": "run", "running": "run", "sat": "sit", "sitting": "sit", "stood": "stand", "threw": "throw",
              "took": "take", "spun": "spin", "swung": "swing", "bent": "bend", "went": "go", "gone": "go",
              "did": "do", "done": "do", "made": "make", "held": "hold", "brought": "bring", "leapt": "leap",
              "sprang": "spring", "knelt": "kneel", "fell": "fall", "rose": "rise", "risen": "rise", "got": "get",
              "lay": "lie", "lying": "lie", "hit": "hit", "strode": "stride", "slid": "slide", "shook": "shake",
              "dove": "dive", "has": "have", "is": "be", "are": "be", "was": "be", "were": "be", "does": "do",
              "goes": "go", "boxes": "box", "punches": "punch", "crouches": "crouch", "stretches": "stretch",
              "reaches": "reach", "marches": "march", "dashes": "dash", "rushes": "rush", "lunges": "lunge"}
_KEEP_ADVERBS = {"slowly", "quickly", "calmly", "fast", "slow", "quick", "rapidly", "briskly", "swiftly"}
_ADVERBS = {"quick": "quickly", "fast": "quickly", "rapidly": "quickly", "swiftly": "quickly",
            "briskly": "quickly", "speedily": "quickly", "hastily": "quickly", "slow": "slowly",
            "leisurely": "slowly", "backwards": "backward", "forwards": "forward",
            "ahead": "forward", "leftward": "left", "leftwards": "left", "rightward": "right",
            "rightwards": "right", "upward": "up", "upwards": "up", "downward": "down", "downwards": "down",
            "your": "their", "ur": "their", "my": "their", "its": "their"}
_COUNTS = {"once", "twice", "times", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten"}
# Possessives and function words: removed with an unknown word that follows them ("kicks [the ball]").
_FUNCTION = {"the", "a", "an", "his", "her", "their", "my", "your", "ur", "its", "at", "to", "toward", "towards",
             "into", "onto", "on", "over", "across", "through", "with", "of", "some", "in", "from", "for", "by",
             "around", "off", "like", "this", "that", "these", "those", "him", "them", "it", "while", "near",
             "next", "against", "along", "up", "down", "out"}
# Words that cannot end a clause ("kicks with his" after "[the ball]" was dropped).
_DANGLING = {"the", "a", "an", "his", "her", "their", "my", "your", "ur", "its", "at", "to", "toward", "towards",
             "into", "onto", "on", "with", "of", "some", "from", "for", "by", "and", "this", "that", "while",
             "near", "against", "like", "through", "across", "over"}
# Direction words whose disagreement with the prompt makes a caption wrong, whatever the embedding says.
_OPPOSITES = {"left": "right", "right": "left", "forward": "backward", "backward": "forward",
              "clockwise": "counterclockwise", "counterclockwise": "clockwise"}
_DIRECTIONS = set(_OPPOSITES) | {"sideways", "circle", "place", "both", "backwards", "around"}

# Clause boundaries, strongest first. "X before Y" keeps the order, "X after Y" swaps it.
_SEQ_SPLIT = re.compile(r"\s*(?:,?\s*\band then\b|,?\s*\band after that\b|,?\s*\band afterwards\b|"
                        r",?\s*\bafter that\b|,?\s*\bafterwards\b|,?\s*\bafterward\b|,?\s*\bthen\b|"
                        r",?\s*\bfollowed by\b|,?\s*\band finally\b|,?\s*\bfinally\b|,?\s*\bnext\b|"
                        r",?\s*\band next\b|,?\s*\bonce done\b|,?\s*\bonce finished\b|,?\s*\bbefore\b|"
                        r"[.;!?]+|,|\s+-+\s+|\s*&\s*|\s*->\s*|\s*=>\s*|\s*\+\s*)\s*")
_AFTER = re.compile(r"^(.*\S)\s+after\s+(?!that\b)(.+)$")
_SUBJECT_IN_CAPTION = re.compile(r"^(?:(?:a|an|the|this|that)\s+\w+|someone|somebody|he|she|they)\s+")


def _third_person(base: str) -> str:
    if base == "be":
        return "is"
    if base == "have":
        return "has"
    if base.endswith(("s", "sh", "ch", "x", "z", "o")):
        return base + "es"
    if base.endswith("y") and len(base) > 1 and base[-2] not in "aeiou":
        return base[:-1] + "ies"
    return base + "s"


class WordingNormalizer:
    """Free-form prompt -> ordered clauses (verb phrases, present tense, 3rd person) in the captions' vocabulary.

    `vocabulary`: the words of the training captions (from the caption index): verbs the captions lack are mapped
    through the synonym table, words they never use are dropped. Without it the user's verbs are only conjugated
    and every word is kept. `caption_verbs`: the verbs the captions use (`caption_verbs()`), so that they are
    recognised as verbs.
    """

    def __init__(self, vocabulary: set[str] | None = None, caption_verbs: set[str] | None = None):
        self.vocabulary = set(vocabulary) if vocabulary else None
        verbs = set(_SYNONYMS) | set(_SYNONYMS.values()) | set(_NOUN_VERBS.values())
        verbs = {v for v in verbs if " " not in v}
        verbs |= {"walk", "run", "jump", "wave", "kick", "squat", "turn", "sit", "punch", "clap", "sidestep",
                  "raise", "stand", "bow", "step", "take", "make", "do", "throw", "swing", "bend", "lower", "lift",
                  "move", "hop", "leap", "jog", "sprint", "spin", "box", "jab", "applaud", "shuffle", "put", "bring",
                  "dance", "go", "stomp", "rise", "stretch", "shake", "look", "nod", "lean", "crawl", "climb",
                  "fall", "dive", "roll", "throw", "catch", "pick", "swim", "wiggle", "flap", "circle"}
        if caption_verbs:           # the 3rd-person verbs the captions use (see `caption_verbs`)
            verbs |= {self.base(w, set()) for w in caption_verbs if w.endswith("s") and len(w) > 2}
        self.verbs = verbs - _HELPERS.difference({"do", "go", "get", "have", "start", "keep"}) - {"is", "has"}
        # "do", "go", "get", "have" count as verbs only when nothing better follows (see _find_verb)

    # ---- word forms
    def base(self, word: str, verbs: set[str] | None = None) -> str:
        """Inflected form -> base form, checked against `verbs` (default: this normaliser's verbs)."""
        verbs = self.verbs if verbs is None else verbs
        if word in _IRREGULAR:
            return _IRREGULAR[word]
        if word in verbs:
            return word
        cands = []
        if word.endswith("ing") and len(word) > 4:
            stem = word[:-3]
            cands += [stem, stem + "e"] + ([stem[:-1]] if len(stem) > 2 and stem[-1] == stem[-2] else [])
        elif word.endswith("ied") and len(word) > 4:
            cands += [word[:-3] + "y"]
        elif word.endswith("ed") and len(word) > 3:
            stem = word[:-2]
            cands += [stem, word[:-1]] + ([stem[:-1]] if len(stem) > 2 and stem[-1] == stem[-2] else [])
        elif word.endswith("ies") and len(word) > 4:
            cands += [word[:-3] + "y"]
        elif word.endswith("es") and len(word) > 3:
            sibilant = word.endswith(("ses", "shes", "ches", "xes", "zes", "oes"))
            cands += [word[:-2], word[:-1]] if sibilant else [word[:-1], word[:-2]]
        elif word.endswith("s") and not word.endswith("ss") and len(word) > 3:
            cands += [word[:-1]]
        for c in cands:
            if c in verbs:
                return c
        if not verbs and cands:            # building the verb list itself: the plain -s strip
            return cands[0]
        return word

    def is_verb(self, word: str) -> bool:
        return self.base(word) in self.verbs

    def conjugate(self, base: str) -> str:
        """Base -> 3rd person present, mapped into the caption vocabulary through the synonym table if needed."""
        form = _third_person(base)
        if self.vocabulary is None or form in self.vocabulary:   # no index: the user's verb, conjugated
            return form
        target = _SYNONYMS.get(base)
        if target is None:
            return form
        head, *rest = target.split()
        return " ".join([_third_person(head)] + rest)

    # ---- text
    def clean(self, text: str) -> str:
        """Lowercase ASCII words and clause punctuation; emojis become words, everything else a space."""
        # emojis stand for actions only when the words name none ("make him 👋"), else they are decoration
        bare = text
        for e in _EMOJI:
            bare = bare.replace(e, " ")
        if not self._has_verb(re.sub(r"[^a-z ]", " ", bare.lower())):
            for e, w in _EMOJI.items():
                text = text.replace(e, w)
        text = unicodedata.normalize("NFKC", text).lower().replace("’", "'").replace("‘", "'")
        text = "".join(c if (c.isascii() and (c.isalnum() or c in " ',.;!?&+-")) or c == ">" else " " for c in text)
        for pat, rep in _CONTRACTIONS:
            text = re.sub(pat, rep, text)
        text = re.sub(r"(?<=[a-z0-9])-(?=[a-z0-9])", " ", text.replace("'", ""))   # "left-footed" -> 2 words
        return re.sub(r"\s+", " ", text).strip()

    def split(self, text: str) -> list[str]:
        """Cleaned text -> raw clauses in temporal order (before any word is changed)."""
        parts = [p.strip() for p in _SEQ_SPLIT.split(text) if p and p.strip()]
        out: list[str] = []
        for p in parts:
            m = _AFTER.match(p)
            if m and self._has_verb(m.group(2)) and self._has_verb(m.group(1)):
                out += [m.group(2), m.group(1)]            # "wave after you jump": jump first
            else:
                out.append(re.sub(r"^after\s+", "", p))
        return out

    def _has_verb(self, text: str) -> bool:
        return any(self.is_verb(w) for w in text.split())

    def clause(self, raw: str) -> str:
        """One raw clause -> a verb phrase without subject ("jumps in place twice"), or "" if nothing is left."""
        s = f" {raw} "
        for pat in _FILLER_PHRASES:
            s = re.sub(pat, " ", s)
        s = re.sub(r"\s+", " ", s).strip()
        s = _CAUSATIVE.sub("", s)
        for pat, rep in _PHRASES:
            s = re.sub(pat, rep, s)
        words = [w for w in s.split() if w not in _FILLERS]
        s = " ".join(words)
        for _ in range(3):
            s = _CAUSATIVE.sub("", s)
            s = _LEADING_SUBJECT.sub("", s)
        words = s.split()
        # "do a hop" / "give a little wave" / "do 3 jumps": the noun is the action
        words = self._noun_actions(words)
        i = self._find_verb(words)
        if i is None:
            words = [w for w in words if w not in _HELPERS]
            return " ".join(self._tidy(words, verb_at=None))
        # before the verb: adverbs stay in front; other content ("right leg kick") follows the verb
        lead = [w for w in words[:i] if w in _KEEP_ADVERBS]
        moved = [w for w in words[:i] if w not in _KEEP_ADVERBS and w not in _HELPERS and w not in _FUNCTION
                 and not _LEADING_SUBJECT.match(w + " ")]
        words = lead + [words[i]] + moved + words[i + 1:]
        return " ".join(self._tidy(words, verb_at=len(lead)))

    def _noun_actions(self, words: list[str]) -> list[str]:
        """"do a lil hop" -> "hop", "do 3 squats" -> "squat three times", "do a left footed kick" -> "kick left"."""
        out, i = [], 0
        light = {"do", "does", "did", "doing", "give", "gives", "gave", "giving", "perform", "performs",
                 "performed", "performing", "bust", "busts", "pull", "pulls", "throw", "throws", "threw",
                 "throwing", "take", "takes", "took", "taking", "make", "makes", "made", "making", "have", "has",
                 "hit", "hits", "nail", "nails", "land", "lands", "execute", "executes"}
        while i < len(words):
            w = words[i]
            if w in light and i + 1 < len(words):
                j, count = i + 1, None
                if words[j] in {"a", "an", "one", "some", "the"}:
                    j += 1
                elif words[j] in _TIMES or words[j] in {"six", "seven", "eight", "nine", "ten"}:
                    count, j = words[j], j + 1
                kept = []                       # up to 3 modifiers before the noun; direction words are kept
                while j < len(words) and j - i <= 4 and words[j] not in _NOUN_VERBS:
                    if words[j] in _DIRECTIONS:
                        kept.append(words[j])
                    j += 1
                noun = words[j] if j < len(words) else None
                if noun in _NOUN_VERBS:
                    out.append(_NOUN_VERBS[noun])
                    if count is not None:
                        out.append(_TIMES.get(count, f"{count} times"))
                    out += kept
                    i = j + 1
                    continue
            out.append(w)
            i += 1
        return out

    def _find_verb(self, words: list[str]) -> int | None:
        """Index of the action verb: the first motion verb, else the first light one ("takes a seat", "does ...")."""
        weak = {"do", "go", "get", "have", "start", "keep", "make", "take"}
        first_weak = None
        for i, w in enumerate(words):
            if w in _HELPERS and not self.is_verb(w):
                continue
            b = self.base(w)
            if b in self.verbs:
                if b not in weak:
                    return i
                first_weak = i if first_weak is None else first_weak
        return first_weak

    def _tidy(self, words: list[str], verb_at: int | None) -> list[str]:
        out: list[tuple[str, bool]] = []      # (word, is a verb: never dropped as unknown)
        k = 0
        while k < len(words):
            w = words[k]
            nxt = words[k + 1] if k + 1 < len(words) else None
            if verb_at is not None and (k == verb_at or (k > 0 and words[k - 1] == "and" and self.is_verb(w))):
                out += [(v, True) for v in self.conjugate(self.base(w)).split()]
            elif w in _TIMES and nxt == "times":                     # "2 times" -> "twice"
                out.append((_TIMES[w], False))
                k += 1
            elif w in _NUMBERS:
                out.append((_NUMBERS[w], False))
            elif w in _ADVERBS and not (self.vocabulary and w in self.vocabulary):
                out.append((_ADVERBS[w], False))
            else:
                out.append((w, False))
            k += 1
        if self.vocabulary:
            out = self._drop_unknown(out)
        words = [w for w, _ in out]
        while words and words[-1] in _DANGLING:
            words.pop()
        return _dedupe(words)

    def _drop_unknown(self, words: list[tuple[str, bool]]) -> list[tuple[str, bool]]:
        """Remove content words the captions never use, with the article/preposition run in front of them."""
        out: list[tuple[str, bool]] = []
        for w, verb in words:
            if verb or w in self.vocabulary or w in _FUNCTION or w in _COUNTS:
                out.append((w, verb))
                continue
            while out and out[-1][0] in _FUNCTION and not out[-1][1]:
                out.pop()
        return out

    def normalize(self, text: str) -> list[str]:
        """Free-form prompt -> its clauses as caption-style verb phrases, in order (possibly [] if nothing moves)."""
        clauses = [c for c in (self.clause(c) for c in self.split(self.clean(text))) if c]
        out: list[str] = []          # a clause without a verb ("..., slowly") belongs to its neighbour
        for c in clauses:
            if out and not self.is_verb(c.split()[0]):
                out[-1] = f"{out[-1]} {c}"
            elif out and not self.is_verb(out[-1].split()[0]):
                out[-1] = f"{c} {out[-1]}"
            else:
                out.append(c)
        return out


def caption_verbs(captions: list[str]) -> set[str]:
    """The verbs of training captions: the word after the subject, and after "then" / "after that" / "afterwards"."""
    verbs: set[str] = set()
    skip = _KEEP_ADVERBS | {"first", "then", "also", "and", "that", "afterwards"}
    for c in captions:
        words = re.findall(r"[a-z]+", strip_subject(c))
        starts = [0] + [i + 1 for i, w in enumerate(words) if w in {"then", "afterwards"} or
                        (w == "that" and i > 0 and words[i - 1] == "after")]
        for i in starts:
            while i < len(words) and words[i] in skip:
                i += 1
            if i < len(words):
                verbs.add(words[i])
    return verbs


def _dedupe(words: list[str]) -> list[str]:
    out: list[str] = []
    for w in words:
        if not out or out[-1] != w:
            out.append(w)
    return out


def sentence(clauses: list[str], subject: str = "a person") -> str:
    """Verb phrases -> one HumanML3D-style caption: "a person X and then Y and then Z."."""
    if not clauses:
        return ""
    return f"{subject} " + " and then ".join(clauses) + "."


def strip_subject(caption: str) -> str:
    """"a man walks forward slowly." -> "walks forward slowly"."""
    c = caption.strip().rstrip(".").strip()
    c = _SUBJECT_IN_CAPTION.sub("", c.lower(), count=1)
    return re.sub(r"^first\s+", "", c)


# --------------------------------------------------------------------------------------------- offline

class _Encoder:
    """Anything that embeds prompts: a TextEncoderSession (.encode), an OrtBackend (.encode_text), a callable."""

    def __init__(self, session):
        if hasattr(session, "encode"):
            self.fn = session.encode
        elif hasattr(session, "encode_text"):
            self.fn = session.encode_text
        elif callable(session):
            self.fn = session
        else:
            raise TypeError(f"text_session must have .encode(list[str]) or .encode_text(list[str]); got "
                            f"{type(session).__name__}")

    def __call__(self, texts: list[str]) -> np.ndarray:
        return np.asarray(self.fn(list(texts)), np.float32)


def load_bundle_index(bundle) -> tuple[CaptionIndex | None, dict]:
    """The caption index and `tca` manifest section of a bundle (a mogo_runtime.Bundle), or (None, {})."""
    section = dict(bundle.manifest.get("tca") or {})
    if not section:
        return None, {}
    name = section.get("file")
    if not isinstance(name, str):
        from .bundle import BundleError
        raise BundleError(f"{bundle.path / 'manifest.json'}: field tca.file missing or not a file name")
    index = CaptionIndex.load(bundle.file(name))
    te = bundle.manifest.get("text_encoder", {}).get("name")
    if index.encoder and te and index.encoder != te:
        from .bundle import BundleError
        raise BundleError(f"{bundle.file(name)}: embeddings from text encoder {index.encoder!r}, the bundle's is "
                          f"{te!r}; re-export the bundle")
    if index.dim != bundle.dims.text_dim:
        from .bundle import BundleError
        raise BundleError(f"{bundle.file(name)}: {index.dim}-dim embeddings, model.text_dim is {bundle.dims.text_dim}")
    return index, section


class OfflineAligner(Aligner):
    """Normalise, split, retrieve: TCA with the bundle's caption index and text encoder, no generative model.

    bundle: a mogo_runtime.Bundle (or None with `index=`); text_session: what embeds prompts (the bundle's
    TextEncoderSession or OrtBackend). method / top_k / ... default to the manifest's `tca` section, else DEFAULTS.
    """

    def __init__(self, bundle=None, text_session=None, method: str | None = None, top_k: int | None = None,
                 temperature: float | None = None, lexical_weight: float | None = None,
                 split_margin: float | None = None, index: CaptionIndex | None = None):
        section: dict = {}
        if index is None and bundle is not None:
            index, section = load_bundle_index(bundle)
        self.index = index
        cfg = {**DEFAULTS, **{k: section[k] for k in DEFAULTS if k in section}}
        for k, v in (("method", method), ("top_k", top_k), ("temperature", temperature),
                     ("lexical_weight", lexical_weight), ("split_margin", split_margin)):
            if v is not None:
                cfg[k] = v
        if cfg["method"] not in METHODS:
            raise ValueError(f"TCA method must be one of {METHODS}, got {cfg['method']!r}")
        self.method, self.top_k = cfg["method"], int(cfg["top_k"])
        self.temperature, self.lexical_weight = float(cfg["temperature"]), float(cfg["lexical_weight"])
        self.split_margin = float(cfg["split_margin"])
        self.encode = _Encoder(text_session) if text_session is not None else None
        vocab = None
        if self.index is not None:
            vocab = {w for c in self.index.captions for w in re.findall(r"[a-z]+", c.lower())}
            single = [not (lb or "").startswith("seq:") for lb in (self.index.labels or [""] * len(self.index))]
            self.single_mask = np.array(single, bool)
            if not self.single_mask.any():
                self.single_mask[:] = True
            if self.encode is None and self.method != "normalize":
                raise ValueError("OfflineAligner with a caption index needs text_session to embed prompts")
        else:
            self._warned = False
        self.normalizer = WordingNormalizer(vocab, caption_verbs(self.index.captions) if self.index else None)

    @property
    def has_index(self) -> bool:
        return self.index is not None

    def align(self, text: str) -> AlignedPrompt:
        clauses = self.normalizer.normalize(text)
        normalized = sentence(clauses)
        if not clauses:   # nothing recognisable: condition on the prompt as given
            return AlignedPrompt(text, None, "none", {"reason": "no motion words found", "clauses": []})
        if self.index is None or self.method == "normalize":
            if self.index is None and self.method != "normalize" and not self._warned:
                warnings.warn("this bundle has no caption index (manifest section 'tca'): TCA only normalises the "
                              "wording; re-export the bundle with a caption index for retrieval", stacklevel=3)
                self._warned = True
            return AlignedPrompt(normalized, None, "normalize", {"clauses": clauses, "normalized": normalized})
        clauses = self._refine_split(clauses)
        hits = self._retrieve(clauses)
        clauses, hits = self._merge_repeats(clauses, hits)
        details = {"clauses": clauses, "normalized": sentence(clauses),
                   "neighbours": [[(self.index.captions[i], round(float(s), 4)) for i, s in h[:3]] for h in hits]}
        best = [h[0] for h in hits]
        nearest_text = sentence([strip_subject(self.index.captions[i]) for i, _ in best])
        if self.method == "blend" and len(clauses) == 1:
            idx = np.array([i for i, _ in hits[0]])
            sims = np.array([s for _, s in hits[0]], np.float32)
            w = np.exp((sims - sims.max()) / max(self.temperature, 1e-6))
            emb = _unit((w[:, None] * self.index.embeddings[idx]).sum(0) / w.sum())
            details["weights"] = np.round(w / w.sum(), 4).tolist()
            return AlignedPrompt(nearest_text, emb.astype(np.float32), "blend", details)
        return AlignedPrompt(nearest_text, None, "nearest", details)

    # ---- retrieval
    def _scores(self, phrases: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Best re-ranked hits for each phrase: (indices (P, k), cosine (P, k), score (P, k)), best first."""
        q = self.encode([sentence([p]) for p in phrases])
        k = max(self.top_k, 1)
        idx, cos = self.index.search(q, max(4 * k, 32), self.single_mask)
        score = cos.copy()
        if self.lexical_weight:
            for r, p in enumerate(phrases):
                score[r] += self.lexical_weight * np.array([_agreement(p, self.index.captions[i]) for i in idx[r]])
        order = np.argsort(-score, axis=1, kind="stable")[:, :k]
        take = lambda a: np.take_along_axis(a, order, axis=1)
        return take(idx), take(cos), take(score)

    def _retrieve(self, clauses: list[str]) -> list[list[tuple[int, float]]]:
        idx, cos, _ = self._scores(clauses)
        return [list(zip(i.tolist(), c.tolist())) for i, c in zip(idx, cos)]

    def _merge_repeats(self, clauses, hits):
        """Neighbouring clauses that retrieve the same action family describe one action: keep the closer one."""
        if self.index.labels is None:
            return clauses, hits
        out_c, out_h = [], []
        for c, h in zip(clauses, hits):
            label = self.index.labels[h[0][0]]
            if out_h and label is not None and self.index.labels[out_h[-1][0][0]] == label:
                if h[0][1] > out_h[-1][0][1]:
                    out_c[-1], out_h[-1] = c, h
                continue
            out_c.append(c)
            out_h.append(h)
        return out_c, out_h

    def _refine_split(self, clauses: list[str]) -> list[str]:
        """Split a clause at a bare "and" when its parts each match the captions better than the whole does."""
        out: list[str] = []
        for c in clauses:
            words = c.split()
            cuts = [i for i, w in enumerate(words) if w == "and" and 0 < i < len(words) - 1
                    and self.normalizer.is_verb(words[i + 1])]
            if not cuts:
                out.append(c)
                continue
            best_parts, best = [c], None
            for cut in cuts:
                parts = [" ".join(words[:cut]), " ".join(words[cut + 1:])]
                _, _, score = self._scores([c] + parts)
                whole, split = float(score[0, 0]), float(score[1:, 0].mean())
                if split > whole + self.split_margin and (best is None or split > best):
                    best_parts, best = parts, split
            out += best_parts
        return out


def _agreement(query: str, caption: str) -> float:
    """+1 per direction word both share, -1 per direction word of the caption that contradicts the query."""
    q = set(query.replace("backwards", "backward").split())
    c = set(re.findall(r"[a-z]+", caption.lower().replace("backwards", "backward")))
    shared = len((q & c) & _DIRECTIONS)
    conflict = sum(1 for w in c & set(_OPPOSITES) if _OPPOSITES[w] in q and w not in q)
    return shared - 2.0 * conflict


# ------------------------------------------------------------------------------------------ chat rewriter

STYLE_PROMPT = """You rewrite requests for a text-to-motion model into the style of the captions it was trained on.
Rules:
- Reply with exactly one sentence and nothing else.
- Start with "a person", use the present tense, describe only what the body does (no objects, places, moods).
- Several actions in a row: keep their order and join them with "and then".
- At most {max_words} words.
- If the request is already in this style, return it unchanged.
Examples of the style:
{examples}"""


class RewriterError(RuntimeError):
    pass


class ChatRewriter(Aligner):
    """TCA with an external language model: an OpenAI-compatible chat completions endpoint, off by default.

    url: the endpoint ("http://host:port/v1/chat/completions"), or its base ("http://host:port" or ".../v1");
    model: the model name the server expects; api_key_env: the environment variable holding the key (sent as
    "Authorization: Bearer ..." when set); examples: training captions for the style prompt (default: a few from
    the fallback's caption index); fallback: the aligner used when the call fails (default: offline wording
    normalisation). Failures warn (`warnings.warn`) and fall back; they never raise.
    """

    def __init__(self, url: str, model: str, api_key_env: str = "MOGO_TCA_API_KEY", timeout: float = 5.0,
                 examples: list[str] | None = None, fallback: Aligner | None = None, max_words: int = 25,
                 num_examples: int = 8):
        if not isinstance(url, str) or not re.match(r"^https?://", url):
            raise ValueError(f"rewriter url must start with http:// or https://, got {url!r}")
        if not model:
            raise ValueError("rewriter model name is empty")
        self.url = _endpoint(url)
        self.model, self.api_key_env, self.timeout, self.max_words = model, api_key_env, float(timeout), max_words
        self.fallback = fallback if fallback is not None else OfflineAligner(method="normalize")
        if examples is None:
            index = getattr(self.fallback, "index", None)
            examples = style_examples(index, num_examples) if index is not None else list(_GENERIC_EXAMPLES)
        self.examples = examples
        self.system_prompt = STYLE_PROMPT.format(max_words=max_words, examples="\n".join(f"- {e}" for e in examples))

    def request_body(self, text: str) -> dict:
        return {"model": self.model, "temperature": 0.0, "max_tokens": 4 * self.max_words,
                "messages": [{"role": "system", "content": self.system_prompt}, {"role": "user", "content": text}]}

    def rewrite(self, text: str) -> str:
        """One call; raises RewriterError with the reason on any failure."""
        import urllib.error  # here, not at the top: ~40 ms of every cold start, for an opt-in feature
        import urllib.request

        headers = {"Content-Type": "application/json", "Accept": "application/json"}
        key = os.environ.get(self.api_key_env)
        if key:
            headers["Authorization"] = f"Bearer {key}"
        req = urllib.request.Request(self.url, data=json.dumps(self.request_body(text)).encode(), headers=headers,
                                     method="POST")
        try:
            with urllib.request.urlopen(req, timeout=self.timeout) as resp:
                raw = resp.read(1 << 20)
        except urllib.error.HTTPError as e:
            raise RewriterError(f"HTTP {e.code} {e.reason}") from None
        except urllib.error.URLError as e:
            raise RewriterError(f"cannot reach it ({e.reason})") from None
        except (TimeoutError, OSError) as e:       # socket.timeout is TimeoutError on 3.10+
            raise RewriterError(f"no answer within {self.timeout:g} s" if isinstance(e, TimeoutError)
                                else f"connection failed ({e})") from None
        try:
            reply = json.loads(raw.decode("utf-8"))
            content = reply["choices"][0]["message"]["content"]
        except (UnicodeDecodeError, json.JSONDecodeError, KeyError, IndexError, TypeError) as e:
            raise RewriterError(f"malformed reply ({type(e).__name__}: {str(e)[:80]})") from None
        return self.check_reply(content)

    def check_reply(self, content) -> str:
        if not isinstance(content, str):
            raise RewriterError(f"malformed reply (content is {type(content).__name__}, not text)")
        lines = [ln.strip() for ln in content.strip().splitlines() if ln.strip()]
        if not lines:
            raise RewriterError("empty reply")
        s = re.sub(r"^(?:rewritten|caption|answer|output)\s*:\s*", "", lines[0], flags=re.I).strip().strip("\"'` ")
        if not s or not re.search(r"[a-zA-Z]", s):
            raise RewriterError(f"reply has no words: {content[:60]!r}")
        if len(s.split()) > 2 * self.max_words:
            raise RewriterError(f"reply too long ({len(s.split())} words): {s[:60]!r}...")
        return s[0].lower() + s[1:]

    def align(self, text: str) -> AlignedPrompt:
        try:
            rewritten = self.rewrite(text)
        except RewriterError as e:
            warnings.warn(f"TCA rewriter {self.url} failed: {e}; using the offline aligner", stacklevel=2)
            out = self.fallback.align(text)
            out.details = {**out.details, "fallback_reason": str(e)}
            return out
        return AlignedPrompt(rewritten, None, "chat", {"url": self.url, "model": self.model})


_GENERIC_EXAMPLES = ("a person walks forward slowly.", "a person jumps in place twice.",
                     "a person waves with the right hand.", "a person sits down on a chair.",
                     "a person walks forward and then turns around to the left.")


def style_examples(index: CaptionIndex, n: int = 8) -> list[str]:
    """A handful of training captions for the style prompt, subject made "a person": one of typical length from
    each of n - 1 action families (all captions when there are no labels), plus one "... and then ..." sequence."""
    labels = index.labels or list(index.captions)
    groups: dict[str, list[int]] = {}
    for i, lb in enumerate(labels):
        groups.setdefault(lb or "", []).append(i)
    singles = sorted(k for k in groups if not k.startswith("seq:"))
    rng = np.random.default_rng(0)
    picked = sorted(rng.choice(len(singles), size=min(n - 1, len(singles)), replace=False).tolist())
    chosen = []
    for j in picked:
        rows = sorted(groups[singles[j]], key=lambda i: (len(index.captions[i]), index.captions[i]))
        chosen.append(rows[len(rows) // 2])
    seq = sorted((i for k, rows in groups.items() if k.startswith("seq:") for i in rows
                  if " and then " in index.captions[i]), key=lambda i: (len(index.captions[i]), index.captions[i]))
    if seq:
        chosen.append(seq[len(seq) // 2])
    return [sentence([re.sub(r"\b(?:his|her)\b", "their", strip_subject(index.captions[i]))]) for i in chosen]


def _endpoint(url: str) -> str:
    url = url.rstrip("/")
    if url.endswith("/chat/completions"):
        return url
    if url.endswith("/v1"):
        return url + "/chat/completions"
    return url + "/v1/chat/completions"


# ------------------------------------------------------------------------------------------- utilities

def make_aligner(bundle, text_session, rewriter_url: str | None = None, rewriter_model: str | None = None,
                 **offline) -> Aligner:
    """The generator's aligner: offline, or a ChatRewriter falling back to it when a rewriter URL is given."""
    aligner = OfflineAligner(bundle, text_session, **offline)
    if rewriter_url:
        return ChatRewriter(rewriter_url, rewriter_model or "default", fallback=aligner)
    return aligner


def apply_alignment(prompts: list[AlignedPrompt], encode: Callable[[list[str]], np.ndarray]) -> np.ndarray:
    """The conditioning embeddings of aligned prompts: each prompt's embedding, or its encoded text."""
    texts = [p.text for p in prompts]
    emb = np.array(encode(texts), np.float32, copy=True)
    for i, p in enumerate(prompts):
        if p.embedding is not None:
            if p.embedding.shape != emb[i].shape:
                raise ValueError(f"aligned embedding has shape {p.embedding.shape}, the text encoder gives "
                                 f"{emb[i].shape}")
            emb[i] = p.embedding
    return emb
