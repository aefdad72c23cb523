"""The token-stream format: a character's motion as the integers it is, for a client that decodes it
(docs/bundle.md, "Token streams").

A stream is a sequence of records, each self-delimiting, all integers little-endian:

    HELLO   u8 1, b"MOGT", u8 version, u8 levels, u16 codebook_size, u8 downsample, 8 bytes decoder id
    TOKENS  u8 2, u32 character, u32 seq, u8 count, count * levels u16 codes      (seq: the first token's index)
    EVENT   u8 3, u32 character, u32 seq, u8 event, u16 n, n bytes UTF-8 text       (seq: the token it applies from)
    WARP    u8 4, u32 character, u32 frame, u16 frames, 5 f64: pose x, pose z, turn, shift x, shift z
    JOINTS  u8 5, u32 character, u32 frame, u16 n, u8 joints, n * joints * 3 f32    (a server's, on request)
    TICK    u8 6, u64 tick, f64 time         (a server's: which of its ticks a message holds, and when it was sent
                                              by the server's monotonic clock in seconds)
    SYNC    u8 7, u32 character, u32 seq, u8 pending, u8 rows, u16 n, u8 eases, u8 flags, rows * levels u16 codes,
            n f32 decoder state, 20 f64 (root, foot lock, planted feet), eases * (u32 start, u16 frames, 8 f64)
                                             (a character's decoder side at token seq, for a client without it)

A HELLO comes first: the client checks it has the decoder the tokens were made for (`decoder_id`: the decoder and
lookup graphs' sha256, so a compact client refuses an fp32 stream, whose frames would differ in the last bits).
Every character's tokens come with consecutive sequence numbers from its START; a gap, a repeat or a token after
END is an error, never a frame made from the wrong context. A WARP carries a steered character's root correction
(control/warp.py: `RootWarp.plan`'s arguments) so the client places frames where the generator placed them. A SYNC
hands a client the decoder side of a character it joins late (or lost): the decoding window, the decoder_step state,
the root integrator, the foot lock, the root warp and its planted feet, so its frames from there on are the
generator's too.

A WebSocket message holds whole records; `RecordReader` also reassembles records cut anywhere (a TCP stream, a file).
"""
from __future__ import annotations

import hashlib
import struct
from dataclasses import dataclass

import numpy as np

from ..bundle.manifest import Manifest
from ..bundle.sections import DECODING_GRAPHS

MAGIC = b"MOGT"
VERSION = 1
HELLO, TOKENS, EVENT, WARP, JOINTS, TICK, SYNC = 1, 2, 3, 4, 5, 6, 7
START, PROMPT, CONTROL, RESTART, END = 1, 2, 3, 4, 5       # events
EVENT_NAMES = {START: "start", PROMPT: "prompt", CONTROL: "control", RESTART: "restart", END: "end"}
MAX_TOKENS_PER_RECORD = 255
MAX_TEXT_BYTES = 4096        # an event's text: a prompt (at most 1,000 characters) or a control request as JSON

_HELLO = struct.Struct("<B4sBBHB8s")
_TOKENS = struct.Struct("<BIIB")
_EVENT = struct.Struct("<BIIBH")
_WARP = struct.Struct("<BIIH5d")
_JOINTS = struct.Struct("<BIIHB")
_TICK = struct.Struct("<BQd")
_SYNC = struct.Struct("<BIIBBHBB")
_SYNC_FLOATS = struct.Struct("<20d")
_EASE = struct.Struct("<IH8d")
MAX_EASES = 3                  # control/warp.py RootWarp keeps 3
TOES, LEFT_CONTACT, RIGHT_CONTACT, WARPED, LEFT_PINNED, RIGHT_PINNED = 1, 2, 4, 8, 16, 32     # a SYNC's flags


class WireError(ValueError):
    """A token stream that breaks the format, or one this client cannot decode."""


@dataclass(frozen=True)
class Hello:
    levels: int
    codebook_size: int
    downsample: int
    decoder_id: bytes
    version: int = VERSION


@dataclass(frozen=True)
class Tokens:
    character: int
    seq: int
    codes: np.ndarray        # (count, levels) int64


@dataclass(frozen=True)
class Event:
    character: int
    seq: int
    event: int
    text: str = ""


@dataclass(frozen=True)
class Warp:
    character: int
    frame: int
    frames: int
    pose: tuple[float, float]
    turn: float
    shift: tuple[float, float]


@dataclass(frozen=True)
class Joints:
    character: int
    frame: int
    joints: np.ndarray       # (n, J, 3) float32 metres, y up


@dataclass(frozen=True)
class Tick:
    tick: int
    time: float


@dataclass(frozen=True)
class Sync:
    """A character's decoder side once its tokens before `seq` were pushed: what a generator's FrameMaker and
    RootWarp hold (decoding.py, control/warp.py), for a client that joins the character late or lost it."""

    character: int
    seq: int                         # the next token of the stream
    pending: int                     # the last `pending` tokens of `window` have no frames yet
    window: np.ndarray               # (rows, levels) int64: the last min(seq, receptive_field + pending) tokens
    decoder_state: np.ndarray        # (n,) float32: the decoder_step state arrays flattened in order; n 0 without
    root: np.ndarray                 # (8,) float64: half-angle, position x z, previous (rot_vel, vel x, vel z),
                                     # the foot lock's offset x z
    toes: np.ndarray | None          # (2, 2) float64: the last frame's toe x z (left, right); None before frames
    contacts: tuple[bool, bool]      # the last frame's toe contacts
    warped: bool                     # RootWarp.active
    eases: tuple[tuple, ...]         # RootWarp.eases: 1 to 3 (start, phi, tx, tz, turn, sx, sz, px, pz, frames)
    pinned: tuple[bool, bool]        # RootWarp.plant: whether each toe (left, right) is planted
    plant: np.ndarray                # (8,) float64: per leg the planted toe's x z (0 where not) and the foot's
                                     # offset x z (control/plant.py)


Record = Hello | Tokens | Event | Warp | Joints | Tick | Sync


def decoder_id(manifest: Manifest, variant: str) -> bytes:
    """8 bytes naming the decoding graphs of `variant` (lookup, decoder, and decoder_step where the bundle has it):
    equal ids decode tokens to the same frames."""
    files = [manifest.graph_file(graph, variant).file for graph in DECODING_GRAPHS if graph in manifest.graph_names]
    return hashlib.sha256("".join(manifest.files[f][1] for f in files).encode()).digest()[:8]


def hello_for(manifest: Manifest, variant: str) -> Hello:
    d = manifest.model
    return Hello(d.num_levels, d.codebook_size, d.downsample, decoder_id(manifest, variant))


def encode(record: Record) -> bytes:
    """One record's bytes."""
    if isinstance(record, Tokens):
        codes = np.asarray(record.codes)
        if codes.ndim != 2 or not 1 <= len(codes) <= MAX_TOKENS_PER_RECORD:
            raise WireError(f"a TOKENS record holds 1 to {MAX_TOKENS_PER_RECORD} tokens (count, levels), "
                            f"got {codes.shape}")
        if codes.min() < 0 or codes.max() > 0xFFFF:
            raise WireError("token codes are u16 on the wire")
        return _TOKENS.pack(TOKENS, record.character, record.seq, len(codes)) + codes.astype("<u2").tobytes()
    if isinstance(record, Event):
        text = record.text.encode("utf-8")
        if len(text) > MAX_TEXT_BYTES or record.event not in EVENT_NAMES:
            raise WireError(f"an EVENT has a known event and at most {MAX_TEXT_BYTES} bytes of text")
        return _EVENT.pack(EVENT, record.character, record.seq, record.event, len(text)) + text
    if isinstance(record, Warp):
        return _WARP.pack(WARP, record.character, record.frame, record.frames, *record.pose, record.turn,
                          *record.shift)
    if isinstance(record, Joints):
        j = np.asarray(record.joints, "<f4")
        if j.ndim != 3 or j.shape[2] != 3 or not 1 <= len(j) <= 0xFFFF or not 1 <= j.shape[1] <= 255:
            raise WireError(f"a JOINTS record holds (1 to 65535 frames, 1 to 255 joints, 3), got {j.shape}")
        return _JOINTS.pack(JOINTS, record.character, record.frame, len(j), j.shape[1]) + j.tobytes()
    if isinstance(record, Tick):
        return _TICK.pack(TICK, record.tick, record.time)
    if isinstance(record, Sync):
        return _encode_sync(record)
    if isinstance(record, Hello):
        return _HELLO.pack(HELLO, MAGIC, record.version, record.levels, record.codebook_size, record.downsample,
                           record.decoder_id)
    raise TypeError(f"not a record: {type(record).__name__}")


def _encode_sync(r: Sync) -> bytes:
    window, state = np.asarray(r.window), np.asarray(r.decoder_state, "<f4").ravel()
    if window.ndim != 2 or len(window) > 255 or len(state) > 0xFFFF or not 1 <= len(r.eases) <= MAX_EASES:
        raise WireError(f"a SYNC holds at most 255 window tokens, 65535 state values and 1 to {MAX_EASES} eases")
    if len(window) and (window.min() < 0 or window.max() > 0xFFFF):
        raise WireError("token codes are u16 on the wire")
    flags = (TOES if r.toes is not None else 0) | (LEFT_CONTACT if r.contacts[0] else 0) | \
        (RIGHT_CONTACT if r.contacts[1] else 0) | (WARPED if r.warped else 0) | \
        (LEFT_PINNED if r.pinned[0] else 0) | (RIGHT_PINNED if r.pinned[1] else 0)
    toes = np.zeros(4) if r.toes is None else np.asarray(r.toes, np.float64).ravel()
    return b"".join([
        _SYNC.pack(SYNC, r.character, r.seq, r.pending, len(window), len(state), len(r.eases), flags),
        window.astype("<u2").tobytes(), state.tobytes(), _SYNC_FLOATS.pack(*np.asarray(r.root, np.float64), *toes,
                                                             *np.asarray(r.plant, np.float64)),
        *(_EASE.pack(int(e[0]), int(e[9]), *map(float, e[1:9])) for e in r.eases)])


def _decode_sync(data, at: int, levels: int) -> Sync:
    _, character, seq, pending, rows, n, eases, flags = _SYNC.unpack_from(data, at)
    if not 1 <= eases <= MAX_EASES or flags > 63 or pending > rows or rows > seq:
        raise WireError(f"byte {at}: a SYNC of {rows} window tokens ({pending} pending) at token {seq} with {eases} "
                        f"eases and flags {flags}")
    o = at + _SYNC.size
    window = np.frombuffer(data, "<u2", rows * levels, o).astype(np.int64).reshape(rows, levels)
    o += 2 * rows * levels
    state = np.frombuffer(data, "<f4", n, o).astype(np.float32)
    o += 4 * n
    floats = np.array(_SYNC_FLOATS.unpack_from(data, o))
    o += _SYNC_FLOATS.size
    kept = []
    for k in range(eases):
        start, frames, *reals = _EASE.unpack_from(data, o + k * _EASE.size)
        kept.append((start, *reals, frames))
        floats = np.concatenate([floats, reals])
    if not np.isfinite(floats).all() or not np.isfinite(state).all():
        raise WireError(f"byte {at}: a SYNC of non-finite numbers")
    toes = floats[8:12].reshape(2, 2) if flags & TOES else None
    return Sync(character, seq, pending, window, state, floats[:8], toes,
                (bool(flags & LEFT_CONTACT), bool(flags & RIGHT_CONTACT)), bool(flags & WARPED), tuple(kept),
                (bool(flags & LEFT_PINNED), bool(flags & RIGHT_PINNED)), floats[12:20])


def _size(data: bytes | memoryview, at: int, levels: int) -> int | None:
    """The length of the record starting at data[at], or None when its length field is not in `data` yet."""
    kind = data[at]
    if kind == TOKENS:
        return None if len(data) < at + _TOKENS.size else _TOKENS.size + 2 * levels * data[at + _TOKENS.size - 1]
    if kind == EVENT:
        if len(data) < at + _EVENT.size:
            return None
        return _EVENT.size + int.from_bytes(data[at + _EVENT.size - 2:at + _EVENT.size], "little")
    if kind == WARP:
        return _WARP.size
    if kind == JOINTS:
        if len(data) < at + _JOINTS.size:
            return None
        n = int.from_bytes(data[at + 9:at + 11], "little")
        return _JOINTS.size + 12 * n * data[at + _JOINTS.size - 1]
    if kind == TICK:
        return _TICK.size
    if kind == SYNC:
        if len(data) < at + _SYNC.size:
            return None
        _, _, _, _, rows, n, eases, _ = _SYNC.unpack_from(data, at)
        return _SYNC.size + 2 * rows * levels + 4 * n + _SYNC_FLOATS.size + eases * _EASE.size
    if kind == HELLO:
        return _HELLO.size
    raise WireError(f"byte {at}: unknown record type {kind}")


def _decode(data, at: int, size: int, levels: int) -> Record:
    kind = data[at]
    if kind == TOKENS:
        _, character, seq, count = _TOKENS.unpack_from(data, at)
        if count == 0:
            raise WireError(f"byte {at}: a TOKENS record of no tokens")
        codes = np.frombuffer(data, "<u2", count * levels, at + _TOKENS.size).astype(np.int64).reshape(count, levels)
        return Tokens(character, seq, codes)
    if kind == EVENT:
        _, character, seq, event, n = _EVENT.unpack_from(data, at)
        if event not in EVENT_NAMES:
            raise WireError(f"byte {at}: unknown event {event}")
        if n > MAX_TEXT_BYTES:
            raise WireError(f"byte {at}: an event's text of {n} bytes (at most {MAX_TEXT_BYTES})")
        try:
            text = bytes(data[at + _EVENT.size:at + size]).decode("utf-8")
        except UnicodeDecodeError:
            raise WireError(f"byte {at}: an event's text is not UTF-8") from None
        return Event(character, seq, event, text)
    if kind == WARP:
        _, character, frame, frames, px, pz, turn, sx, sz = _WARP.unpack_from(data, at)
        if not np.all(np.isfinite([px, pz, turn, sx, sz])):
            raise WireError(f"byte {at}: a WARP of non-finite numbers")
        return Warp(character, frame, frames, (px, pz), turn, (sx, sz))
    if kind == TICK:
        _, tick, when = _TICK.unpack_from(data, at)
        if not np.isfinite(when):
            raise WireError(f"byte {at}: a TICK at a non-finite time")
        return Tick(tick, when)
    if kind == JOINTS:
        _, character, frame, n, joints = _JOINTS.unpack_from(data, at)
        j = np.frombuffer(data, "<f4", n * joints * 3, at + _JOINTS.size).reshape(n, joints, 3).astype(np.float32)
        if not len(j) or not joints or not np.isfinite(j).all():
            raise WireError(f"byte {at}: a JOINTS record of no frames, no joints or non-finite numbers")
        return Joints(character, frame, j)
    if kind == SYNC:
        return _decode_sync(data, at, levels)
    _, magic, version, lv, codebook, downsample, ident = _HELLO.unpack_from(data, at)
    if magic != MAGIC:
        raise WireError(f"byte {at}: not a mogo token stream (magic {magic!r})")
    if version != VERSION:
        raise WireError(f"byte {at}: token-stream version {version}; this client reads version {VERSION}")
    return Hello(lv, codebook, downsample, ident, version)


class RecordReader:
    """Bytes in, whole records out: `feed(data)` -> the records completed by `data`. The levels per token come from
    the stream's HELLO (`levels` until then, for a reader that knows them); a record cut short stays buffered."""

    def __init__(self, levels: int | None = None, max_buffer: int = 1 << 20):
        self.levels, self.max_buffer = levels, max_buffer
        self.buffer = bytearray()
        self.offset = 0       # bytes consumed before the buffer, for messages

    def feed(self, data: bytes) -> list[Record]:
        self.buffer += data
        if len(self.buffer) > self.max_buffer:
            raise WireError(f"{len(self.buffer)} bytes buffered without a whole record (at most {self.max_buffer})")
        out, at, view = [], 0, bytes(self.buffer)
        while at < len(view):
            if view[at] != HELLO and self.levels is None:
                raise WireError(f"byte {self.offset + at}: a {view[at]} record before the stream's HELLO")
            size = _size(view, at, self.levels or 0)
            if size is None or at + size > len(view):
                break
            try:
                record = _decode(view, at, size, self.levels or 0)
            except WireError as e:
                raise WireError(f"{e} (stream offset {self.offset})") from None
            if isinstance(record, Hello):
                self.levels = record.levels
            out.append(record)
            at += size
        del self.buffer[:at]
        self.offset += at
        return out

    @property
    def pending(self) -> int:
        """Bytes of a record not yet whole."""
        return len(self.buffer)


def read_message(data: bytes, levels: int | None = None) -> list[Record]:
    """The records of one message that holds whole records (a WebSocket message); a cut record is an error."""
    reader = RecordReader(levels, max_buffer=max(len(data), 1))
    records = reader.feed(data)
    if reader.pending:
        raise WireError(f"the message ends inside a record ({reader.pending} bytes left over)")
    return records
