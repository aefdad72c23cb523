"""TCA through an external language model, apart from the runtime a device ships: `ChatRewriter` calls an
OpenAI-compatible /v1/chat/completions endpoint with a style prompt built from a few training captions.

    from mogo_rewriter import ChatRewriter
    gen.aligner = ChatRewriter("http://localhost:8000/v1", "qwen2.5", fallback=gen.aligner)

Any failure (timeout, HTTP error, malformed reply) warns and returns the fallback aligner's result. It is its own
package because a game or an edge device has no chat model to call: `mogo_runtime` never imports it (only the
CLI's --rewriter-url does), so a device build can leave it out. urllib is imported on the first call (~40 ms).
"""
from __future__ import annotations

import json
import os
import re
import warnings

import numpy as np

from mogo_runtime.tca.base import AlignedPrompt, Aligner
from mogo_runtime.tca.index import CaptionIndex
from mogo_runtime.tca.offline import OfflineAligner
from mogo_runtime.tca.wording import sentence, strip_subject

STYLE_PROMPT = """You rewrite requests for a text-to-motion model into the style of the captions it was trained on.
Rules:
- Reply with exactly one sentence and nothing else.
- Start with "a person", use the present tense, describe only what the body does (no objects, places, moods).
- Several actions in a row: keep their order and join them with "and then".
- At most {max_words} words.
- If the request is already in this style, return it unchanged.
Examples of the style:
{examples}"""
# The examples when the fallback has no caption index to take them from.
GENERIC_EXAMPLES = ("a person walks forward slowly.", "a person jumps in place twice.",
                    "a person waves with the right hand.", "a person sits down on a chair.",
                    "a person walks forward and then turns around to the left.")


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
        self.fallback = fallback if fallback is not None else OfflineAligner()
        if examples is None:
            index = getattr(self.fallback, "index", None)
            examples = style_examples(index, num_examples) if index is not None else list(GENERIC_EXAMPLES)
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
        return AlignedPrompt(rewritten, method="chat", details={"url": self.url, "model": self.model})


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

    def typical(rows: list[int]) -> int:          # the caption of median length
        return sorted(rows, key=lambda i: (len(index.captions[i]), index.captions[i]))[len(rows) // 2]

    chosen = [typical(groups[singles[j]]) for j in picked]
    seq = [i for k, rows in groups.items() if k.startswith("seq:") for i in rows if " and then " in index.captions[i]]
    if seq:
        chosen.append(typical(seq))
    return [sentence([re.sub(r"\b(?:his|her)\b", "their", strip_subject(index.captions[i]))]) for i in chosen]


def _endpoint(url: str) -> str:
    url = url.rstrip("/")
    if url.endswith("/chat/completions"):
        return url
    return url + ("/chat/completions" if url.endswith("/v1") else "/v1/chat/completions")
