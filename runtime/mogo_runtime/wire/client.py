"""A decode-only client: tokens in, frames out, with the bundle's decoding graphs alone (lookup, decoder,
decoder_step; no step graph, no text encoder: on `base`'s compact variant 0.9 MB of graphs instead of 32 MB).

    client = MotionClient("bundles/base", variant="compact")     # the variant the tokens were generated with
    for message in connection:                                   # token-stream records (wire/format.py)
        for ident, frames in client.receive(message).items():
            show(ident, frames.joints)                           # (n, J, 3) metres, y up

A character's frames are made as a generator makes them (decoding.FrameMaker: the causal decoder, the root
integrated, planted toes held; then the root corrections of a steered character, replayed from its WARP records),
so on the same machine they are the generating runtime's joints bit for bit; a character joined late starts from the
stream's SYNC of it, so its frames from there are the generator's too. A game-owned root (`set_root`) is not in the
stream: each machine puts the frames on the capsule its own game replicates.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..bundle.folder import Bundle
from ..bundle.sections import DECODING_GRAPHS
from ..control.plant import legs_of
from ..control.warp import Ease, RootWarp
from ..decoding import MAX_CHUNK, FrameMaker, Frames, check_chunk, decode_due
from ..engine import MotionDecoder
from .format import END, PROMPT, START, Event, Hello, Record, RecordReader, Sync, Tokens, Warp, WireError, decoder_id

MAX_CHARACTERS = 100_000     # characters one client follows at once


@dataclass
class ClientCharacter:
    """One character as a client knows it: its prompt, the next token it expects, its frames so far."""

    ident: int
    text: str
    frames: FrameMaker
    next_seq: int
    warp: RootWarp
    ended: bool = False


class MotionClient:
    """Follows the characters of one token stream. `chunk`: tokens per decode, as a generator's stream's (frames
    are the same bits whatever the chunk)."""

    def __init__(self, bundle: Bundle | str | Path, variant: str = "fp32", threads: int = 1, chunk: int = 1):
        self.bundle = bundle if isinstance(bundle, Bundle) else Bundle.load(bundle, variant, DECODING_GRAPHS)
        self.decoder = MotionDecoder(self.bundle, variant, threads)
        self.dims, self.skeleton, self.chunk = self.bundle.dims, self.bundle.skeleton, check_chunk(chunk)
        self.legs = legs_of(self.skeleton)
        self.id = decoder_id(self.bundle.manifest, variant)
        self.reader = RecordReader()
        self.characters: dict[int, ClientCharacter] = {}
        self.hello: Hello | None = None

    def receive(self, data: bytes) -> dict[int, Frames]:
        """Bytes of the stream (whole records or not) -> the new frames of each character they complete."""
        return self.apply(self.reader.feed(data))

    def apply(self, records: list[Record]) -> dict[int, Frames]:
        out: dict[int, list[Frames]] = {}
        waiting: dict[int, ClientCharacter] = {}     # tokens pushed, frames not made: decoded together at the end
        for record in records:
            if isinstance(record, Hello):
                self._hello(record)
            elif self.hello is None:
                raise WireError("a record before the stream's HELLO")
            elif isinstance(record, Tokens):
                c = self._character(record.character)
                if record.seq != c.next_seq:
                    raise WireError(f"character {c.ident}: token {record.seq} where {c.next_seq} was next "
                                    f"({'a token was lost' if record.seq > c.next_seq else 'a token came twice'})")
                if (record.codes >= self.dims.codebook_size).any():
                    raise WireError(f"character {c.ident}: a code outside the codebook ({self.dims.codebook_size})")
                for token in record.codes:
                    n = c.frames.due()
                    if n:       # its earlier tokens' frames first, alone: the maker holds only a window of tokens
                        out.setdefault(c.ident, []).append(self._frames(c, n))
                    c.frames.push(token)
                c.next_seq += len(record.codes)
                waiting[c.ident] = c
            elif isinstance(record, Warp):
                c = self._character(record.character)
                self._flush(c, out)     # the frames before it were placed without it
                c.warp.plan(record.frame, record.frames, np.array(record.pose), record.turn, record.shift)
            elif isinstance(record, Sync):
                self._sync(record, out)
            elif isinstance(record, Event):
                self._event(record, out)
        self._decode(waiting.values(), out)
        return {ident: _joined(chunks) for ident, chunks in out.items()}

    def _decode(self, characters, out: dict[int, list[Frames]]) -> None:
        """The frames due of many characters, one decoder call per number of tokens due (a crowd's tick arrives as
        one message): the same bits as one character at a time, whatever the chunk."""
        groups: dict[int, list[ClientCharacter]] = {}
        for c in characters:
            n = c.frames.due()
            if n and not c.ended:
                groups.setdefault(n, []).append(c)
        for n, group in groups.items():
            makers = [c.frames for c in group]
            for c, frames in zip(group, FrameMaker.frames_many(makers, decode_due(self.decoder, makers, n))):
                frames.joints = c.warp.joints(frames.index, frames.joints)
                out.setdefault(c.ident, []).append(frames)

    def _hello(self, hello: Hello) -> None:
        d = self.dims
        if (hello.levels, hello.codebook_size, hello.downsample) != (d.num_levels, d.codebook_size, d.downsample):
            raise WireError(f"the stream's tokens are {hello.levels} levels of {hello.codebook_size} codes, "
                            f"{hello.downsample} frames each; this bundle's are {d.num_levels} of {d.codebook_size}, "
                            f"{d.downsample}")
        if hello.decoder_id != self.id:
            raise WireError(f"the stream was generated for decoder {hello.decoder_id.hex()}, this client has "
                            f"{self.id.hex()} ({self.decoder.variant} of {self.bundle.path}): open the bundle and "
                            f"variant the server runs")
        self.hello = hello

    def _event(self, event: Event, out: dict[int, list[Frames]]) -> None:
        if event.event == START:
            old = self.characters.get(event.character)
            if old is not None and not old.ended:
                raise WireError(f"character {event.character} started twice")
            if len(self.characters) >= MAX_CHARACTERS:
                raise WireError(f"more than {MAX_CHARACTERS} characters in one stream")
            maker = FrameMaker(self.dims, self.skeleton, self.chunk, self.decoder.decoder_state)
            # frame numbers as the generator's (WARP records name frames); a character that started before the
            # client joined decodes from an empty window, at the origin, unless a SYNC of it follows
            maker.frames = event.seq * self.dims.downsample
            self.characters[event.character] = ClientCharacter(event.character, event.text, maker, event.seq,
                                                               RootWarp(self.legs))
            return
        c = self._character(event.character)
        if event.event == PROMPT:
            c.text = event.text
        elif event.event == END:
            self._flush(c, out)
            c.ended = True
            del self.characters[c.ident]

    def _sync(self, sync: Sync, out: dict[int, list[Frames]]) -> None:
        """The character's decoder side from the generator's: what it had here (a window, tokens not decoded)
        is dropped, and its frames go on from the generator's frame (seq - pending) * downsample."""
        c, d = self._character(sync.character), self.dims
        if c.ident in out:
            raise WireError(f"character {c.ident}: a SYNC after its frames in the same message")
        rows = min(sync.seq, d.receptive_field + sync.pending)
        if sync.pending > MAX_CHUNK or len(sync.window) != rows:
            raise WireError(f"character {c.ident}: a SYNC at token {sync.seq} holds {len(sync.window)} window tokens "
                            f"({sync.pending} pending); {rows} expected, at most {MAX_CHUNK} pending")
        if (sync.window >= d.codebook_size).any():
            raise WireError(f"character {c.ident}: a code outside the codebook ({d.codebook_size})")
        shapes = self.decoder.decoder_state or ()
        if len(sync.decoder_state) != sum(a * b for a, b in shapes):
            raise WireError(f"character {c.ident}: a SYNC of {len(sync.decoder_state)} decoder state values; this "
                            f"decoder's state has {sum(a * b for a, b in shapes)}")
        maker = FrameMaker(d, self.skeleton, max(self.chunk, sync.pending), self.decoder.decoder_state)
        maker.chunk = self.chunk        # the window holds the pending tokens, the chunk stays the client's
        maker.tokens[len(maker.tokens) - rows:] = sync.window
        maker.count, maker.pending, maker.frames = sync.seq, sync.pending, (sync.seq - sync.pending) * d.downsample
        if maker.state is not None:
            maker.state = np.split(sync.decoder_state, np.cumsum([a * b for a, b in shapes])[:-1])
        root, lock = maker.joints.root, maker.joints.lock
        root.angle, root.position, root.previous = float(sync.root[0]), sync.root[1:3].copy(), sync.root[3:6].copy()
        lock.offset = sync.root[6:8].copy()
        lock.previous = None if sync.toes is None else (sync.toes.copy(), np.array(sync.contacts))
        c.frames, c.next_seq, c.warp = maker, sync.seq, RootWarp(self.legs)
        c.warp.eases.clear()
        c.warp.eases.extend(Ease(*e) for e in sync.eases)
        c.warp.active = sync.warped
        c.warp.plant.load(sync.pinned, sync.plant)

    def _character(self, ident: int) -> ClientCharacter:
        c = self.characters.get(ident)
        if c is None:
            raise WireError(f"character {ident}: records before its START (or after its END)")
        return c

    def _flush(self, c: ClientCharacter, out: dict[int, list[Frames]]) -> None:
        n = c.frames.due(final=True)
        if n:
            out.setdefault(c.ident, []).append(self._frames(c, n))

    def _frames(self, c: ClientCharacter, n: int) -> Frames:
        frames = c.frames.frames_from(decode_due(self.decoder, [c.frames], n)[0])
        frames.joints = c.warp.joints(frames.index, frames.joints)
        return frames


def _joined(chunks: list[Frames]) -> Frames:
    if len(chunks) == 1:
        return chunks[0]
    return Frames(chunks[0].index, np.concatenate([f.features for f in chunks]),
                  np.concatenate([f.joints for f in chunks]))
