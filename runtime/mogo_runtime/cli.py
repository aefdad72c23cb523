"""The `mogo` command: generate motion files, stream frames to a game, describe a bundle.

    mogo generate "a person walks forward and then jumps" -o walk.bvh -o walk.gif --seconds 6 --seed 1
    mogo stream "a person waves" --seed 2 | my_game        # one JSON line per frame on stdout
    mogo info bundles/base                                  # graphs, variants, sizes, dims, verified hashes
    mogo generate "yo make the dude do a lil hop" --align -o hop.bvh   # TCA: prompt rewritten in caption style

`--align` conditions on the prompt rewritten into the training captions' style (TCA, mogo_runtime/tca/): offline
with the bundle's caption index, or with `--rewriter-url URL --rewriter-model NAME` by an OpenAI-compatible chat
endpoint (key from $MOGO_TCA_API_KEY), falling back to the offline aligner when it fails. The aligned text is
printed on stderr.

The bundle is `--bundle PATH`, else $MOGO_BUNDLE, else bundles/base. Bad input ends with one line on stderr
starting with "mogo: error:" and exit status 2, as argparse does, never with a traceback.
"""
from __future__ import annotations

import argparse
import json
import os
import queue
import sys
import threading
import time
import warnings
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

from .bundle.folder import Bundle, read_manifest
from .bundle.manifest import SCHEMA_VERSION
from .bundle.sampling import SamplingConfig
from .bundle.sections import BundleError
from .control.commands import Request, parse_request
from .outputs.extras import MissingExtra
from .outputs.motion import RIG_FORMATS, SAVE_FORMATS, check_output_path
from .outputs.rig import RIGS, load_rig
from .serve import command as serve_command
from .text import MAX_PROMPT_CHARS, check_texts, load_tokenizer

DEFAULT_BUNDLE = "bundles/base"
EXIT_USAGE = 2
JOINT_DECIMALS = 4     # metres: 0.1 mm
MAX_MESSAGE = 1000     # characters of an error line
MAX_LINE_BYTES = 1 << 20   # a line of --follow's stdin: a prompt (<= 4 * MAX_PROMPT_CHARS bytes) or a JSON request
                           # (a 20,000-point path; control/targets.py bounds the points)


class UsageError(Exception):
    """Bad input from the user: reported as `mogo: error: ...`, exit status 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        raise UsageError(f"{message} (see `{self.prog} --help`)")


def default_bundle() -> tuple[Path, bool]:
    """The bundle to use when --bundle is not given, and whether it came from $MOGO_BUNDLE."""
    env = os.environ.get("MOGO_BUNDLE")
    return (Path(env), True) if env else (Path(DEFAULT_BUNDLE), False)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="mogo", description="Text to 3D human motion with a mogo bundle (onnxruntime, no torch).")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser, metavar="COMMAND")

    def add_sampling_args(p: argparse.ArgumentParser) -> None:
        p.add_argument("--temperature", type=float, help="0 = greedy; default: the bundle's")
        p.add_argument("--top-k", type=int, help="keep the k likeliest codes, 0 = all; default: the bundle's")
        p.add_argument("--top-p", type=float, help="nucleus sampling mass in (0, 1]; default: the bundle's")
        p.add_argument("--guidance", type=float, help="classifier-free guidance scale, 1 = off; default: the bundle's")
        p.add_argument("--threads", type=int, default=1,
                       help="onnxruntime threads (default 1: fastest per step on a busy machine)")

    def add_generation_args(p: argparse.ArgumentParser) -> None:
        p.add_argument("text", help="what the person does, e.g. \"a person walks forward and then jumps\"")
        p.add_argument("--bundle", type=Path, help=f"bundle folder (default: $MOGO_BUNDLE or {DEFAULT_BUNDLE})")
        p.add_argument("--seconds", type=float, help="fixed length; default: the model decides when to stop")
        p.add_argument("--seed", type=int, default=0, help="random seed; same seed, same motion (default 0)")
        v = p.add_mutually_exclusive_group()
        v.add_argument("--int8", action="store_const", const="int8", dest="variant",
                       help="use the bundle's int8 graphs (faster on CPU)")
        v.add_argument("--variant", dest="variant", help="bundle variant by name (default fp32)")
        add_sampling_args(p)
        p.add_argument("--align", action=argparse.BooleanOptionalAction, default=None,
                       help="rewrite the prompt into the training captions' style first (TCA; default: off)")
        p.add_argument("--rewriter-url", metavar="URL",
                       help="TCA with an OpenAI-compatible chat endpoint (implies --align; key from "
                            "$MOGO_TCA_API_KEY); falls back to the offline aligner if it fails")
        p.add_argument("--rewriter-model", metavar="NAME", help="model name for --rewriter-url (default: 'default')")

    gen = sub.add_parser("generate", help="write motion files (" + ", ".join(SAVE_FORMATS) + ")",
                         description="Generate one motion and write it to every -o file (format by extension: "
                                     + ", ".join(SAVE_FORMATS) + ").")
    add_generation_args(gen)
    gen.add_argument("-o", "--output", action="append", required=True, type=Path, metavar="FILE",
                     help="output file, repeatable: walk.bvh, walk.glb, walk.gif, walk.json, walk.npy, walk.mp4")
    gen.add_argument("--rig", metavar="RIG",
                     help="write the .glb and .bvh files on a game rig: " + ", ".join(RIGS) + ", or a rig file "
                          "(.json, see `mogo rigs`); default: .glb on humanml3d, .bvh on the bundle's skeleton")
    gen.add_argument("--in-place", action="store_true",
                     help="with .glb/.bvh: keep the hips over the origin (no root motion; turning stays)")
    gen.set_defaults(run=cmd_generate)

    stream = sub.add_parser("stream", help="print one JSON line per frame as frames are decoded",
                            description='One JSON object per line on stdout, flushed per frame: '
                                        '{"frame": i, "time": seconds, "joints": [[x, y, z], ...]} '
                                        '(metres, y up, joint order of the bundle\'s skeleton).')
    add_generation_args(stream)
    stream.add_argument("--follow", action="store_true",
                        help="read requests from stdin, one per line, each followed from the next token: a "
                             'prompt, or a JSON object ({"prompt": ..., "goal": [x, z], "speed": ...}, {"path": '
                             '[[x, z], ...]}, {"velocity": [vx, vz], "facing": [x, z]}, {"root": [x, z, heading]}, '
                             '{"release": true}; control needs a bundle with a control section); an {"event": ...} '
                             "line marks each change and an arrival (needs a bundle trained for endless streams)")
    stream.set_defaults(run=cmd_stream)

    crowd = sub.add_parser("crowd", help="many characters at once, stepped together: a motion file each",
                           description="Run N characters in one loop, each with its own prompt and seed, one batched "
                                       "step per tick, and write character i's motion to OUT/character_<i>.<format>. "
                                       "Each motion is, bit for bit, what `mogo stream` gives that prompt and seed on the "
                                       "same variant (and `mogo generate`'s to float rounding). Needs a "
                                       "fixed-capacity variant: portable, int8_fixed or compact.")
    crowd.add_argument("text", nargs="+", help="prompts, handed to the characters in turn")
    crowd.add_argument("-n", "--characters", type=int, help="how many characters (default: one per prompt)")
    crowd.add_argument("--seconds", type=float, required=True, help="length of every motion")
    crowd.add_argument("--seed", type=int, default=0, help="character i gets seed + i (default 0)")
    crowd.add_argument("--bundle", type=Path, help=f"bundle folder (default: $MOGO_BUNDLE or {DEFAULT_BUNDLE})")
    crowd.add_argument("--variant", default="int8_fixed", help="portable, int8_fixed (default) or compact")
    add_sampling_args(crowd)
    crowd.add_argument("-o", "--out", type=Path, required=True, metavar="DIR", help="folder for the motion files")
    crowd.add_argument("--format", default="bvh", choices=[s.lstrip(".") for s in SAVE_FORMATS if s != ".mp4"],
                       help="file format of every motion (default bvh)")
    crowd.add_argument("--rig", metavar="RIG", help="with --format glb or bvh: a game rig (see `mogo rigs`)")
    crowd.set_defaults(run=cmd_crowd, align=False, rewriter_url=None, rewriter_model=None)

    rigs = sub.add_parser("rigs", help="the game rigs --rig knows, and how to add your own",
                          description="The rigs shipped with mogo (for --rig); a rig file of your own works the same.")
    rigs.add_argument("rig", nargs="?", help="print this rig's file (a name, or a rig file to check)")
    rigs.set_defaults(run=cmd_rigs)

    serve_command.add_parser(sub)

    info = sub.add_parser("info", help="what a bundle holds, and whether its files are intact")
    info.add_argument("bundle", nargs="?", type=Path, help=f"bundle folder (default: $MOGO_BUNDLE or {DEFAULT_BUNDLE})")
    info.set_defaults(run=cmd_info)
    return parser


def main(argv: list[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
        return args.run(args)
    except UsageError as e:
        return _fail(str(e))
    except (BundleError, ValueError, OSError, MissingExtra) as e:  # BundleError and OutputError included
        return _fail(str(e))
    except MemoryError:
        return _fail("out of memory (ask for less: fewer characters, shorter motions)")
    except KeyboardInterrupt:
        print("mogo: interrupted", file=sys.stderr)
        return 130


def _fail(message: str) -> int:
    print(f"mogo: error: {one_line(message)}", file=sys.stderr)
    return EXIT_USAGE


def one_line(message: str, most: int = MAX_MESSAGE) -> str:
    """`message` as one line of at most `most` characters: control characters (a newline in a file name) escaped,
    the rest cut with a note of how much, so a hostile name or prompt cannot add lines or flood the terminal."""
    text = "".join(c if c.isprintable() else repr(c)[1:-1] for c in message)
    return text if len(text) <= most else f"{text[:most]}... ({len(text) - most:,} more characters)"


def _load_generator(args):
    from .generator import MotionGenerator   # onnxruntime is imported only by commands that run graphs

    path, from_env = (args.bundle, False) if args.bundle is not None else default_bundle()
    if args.bundle is None and not path.exists():
        where = "from $MOGO_BUNDLE" if from_env else "the default bundle path"
        raise BundleError(f"{path}: bundle folder not found ({where}); pass --bundle PATH or set $MOGO_BUNDLE, "
                          f"or build bundles/base with `make demo`")
    # The generator loads and checks only the files of the variant it runs (cold start).
    # No argparse default for --variant: argparse would then miss "--int8 --variant fp32" as a conflict.
    gen = MotionGenerator(path, variant="fp32" if args.variant is None else args.variant, threads=args.threads)
    if args.rewriter_url:  # the offline aligner stays as the fallback; sessions are opened once
        from mogo_rewriter import ChatRewriter

        gen.aligner = ChatRewriter(args.rewriter_url, args.rewriter_model or "default", fallback=gen.aligner)
    return gen


def _align(args) -> bool:
    if args.rewriter_model and not args.rewriter_url:
        raise UsageError("--rewriter-model needs --rewriter-url")
    if args.rewriter_url and args.align is False:
        raise UsageError("--rewriter-url and --no-align contradict each other")
    return bool(args.rewriter_url) if args.align is None else args.align


@contextmanager
def _warnings_as_lines():
    """Library warnings (a TCA fallback, a bundle without caption index) as one `mogo: warning:` line each."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            yield
        finally:
            for w in caught:
                print(f"mogo: warning: {w.message}", file=sys.stderr)


def _sampling(args, defaults: SamplingConfig) -> SamplingConfig:
    """The bundle's defaults with the flags given on the command line (--top-k 0: no top-k cut)."""
    given = {"temperature": args.temperature, "top_k": args.top_k, "top_p": args.top_p, "guidance": args.guidance}
    return replace(defaults, **{k: v for k, v in given.items() if v is not None})


def cmd_generate(args) -> int:
    check_texts([args.text])         # before any work: an empty prompt should not cost a bundle load
    align = _align(args)
    for out in args.output:            # before any work: a typo should not cost a generation
        check_output_path(out)
    rig = load_rig(args.rig) if args.rig else None
    if (rig or args.in_place) and not any(out.suffix.lower() in RIG_FORMATS for out in args.output):
        raise UsageError(f"--rig and --in-place apply to {' and '.join(RIG_FORMATS)} outputs; none was given")
    gen = _load_generator(args)
    fixed = gen.tokens_for(args.seconds)
    sampling = _sampling(args, gen.sampling_defaults)
    show = sys.stderr.isatty()

    def progress(step: int, limit: int) -> None:
        print(f"\rmogo: generating, token {step}/{limit}", end="", file=sys.stderr, flush=True)

    start = time.perf_counter()
    with _warnings_as_lines():
        motion = gen.generate(args.text, seconds=args.seconds, seed=args.seed, progress=progress if show else None,
                              align=align, sampling=sampling)
    took = time.perf_counter() - start
    if show:
        print(file=sys.stderr)
    if motion.aligned_text is not None:     # aligned, or split into the actions it names (" | " between them)
        print(f"mogo: {'aligned prompt' if align else 'actions'}: {motion.aligned_text!r}", file=sys.stderr)
    if fixed:
        ended = "fixed length"
    else:
        ended = "hit max length" if len(motion.tokens) == gen.max_tokens else "model ended it"
    print(f"mogo: {motion.num_frames} frames, {motion.seconds:.2f} s ({ended}) in {took:.2f} s "
          f"[{gen.variant}, seed {args.seed}]", file=sys.stderr)
    for out in args.output:
        on_rig = out.suffix.lower() in RIG_FORMATS and (rig or args.in_place)
        print(f"wrote {motion.save(out, rig=rig, in_place=args.in_place) if on_rig else motion.save(out)}")
    return 0


def cmd_crowd(args) -> int:
    from .crowd import Crowd

    check_texts(args.text)
    count = len(args.text) if args.characters is None else args.characters
    if isinstance(count, bool) or not 1 <= count <= 100_000:
        raise UsageError(f"--characters must be between 1 and 100000, got {count}")
    rig = load_rig(args.rig) if args.rig else None
    suffix = "." + args.format
    if rig and suffix not in RIG_FORMATS:
        raise UsageError(f"--rig applies to {' and '.join(RIG_FORMATS)} files, not {suffix}")
    paths = [args.out / f"character_{i:0{len(str(count - 1))}d}{suffix}" for i in range(count)]
    check_output_path(paths[0])
    gen = _load_generator(args)
    crowd = Crowd(gen, sampling=_sampling(args, gen.sampling_defaults))
    if count > crowd.max_characters:      # refused before any character costs memory
        raise UsageError(f"--characters {count}: the memory available holds {crowd.max_characters} characters of this "
                         f"bundle ({crowd.character_bytes / 2 ** 20:.1f} MiB of step cache each)")
    start = time.perf_counter()
    members = [crowd.add(args.text[i % len(args.text)], seed=args.seed + i, seconds=args.seconds, record=True)
               for i in range(count)]
    added = time.perf_counter()
    ticks = 0
    while crowd:
        crowd.tick()
        ticks += 1
        if sys.stderr.isatty():
            print(f"\rmogo: crowd of {count}, tick {ticks}", end="", file=sys.stderr, flush=True)
    took = time.perf_counter() - added
    if sys.stderr.isatty():
        print(file=sys.stderr)
    seconds = gen.tokens_for(args.seconds) * gen.dims.downsample / gen.dims.fps
    print(f"mogo: {count} characters x {seconds:.2f} s of motion in {took:.2f} s ({ticks} ticks, "
          f"{count * seconds / took:.0f} character-seconds per second; prompts encoded in {added - start:.2f} s) "
          f"[{gen.variant}]", file=sys.stderr)
    for c, path in zip(members, paths):
        motion = c.motion()
        print(f"wrote {motion.save(path, rig=rig) if rig else motion.save(path)}")
    return 0


def cmd_rigs(args) -> int:
    if args.rig:
        print(json.dumps(load_rig(args.rig).to_dict(), indent=1))
        return 0
    for name in RIGS:
        rig = load_rig(name)
        print(f"{name:10s} {rig.num_bones:3d} bones, {rig.rest_pose}-pose: {rig.description}")
    print("\nA rig of your own: `mogo rigs mixamo > my_rig.json`, edit the bone names and rest-pose heads (metres, y "
          "up, facing +z), then --rig my_rig.json. docs/rigs.md describes the format.")
    return 0


def cmd_stream(args) -> int:
    check_texts([args.text])         # before any work: an empty prompt should not cost a bundle load
    align = _align(args)
    if args.follow and (sys.stdin is None or sys.stdin.closed):
        raise UsageError("--follow reads new prompts from stdin, and stdin is closed")
    requests = _read_lines(sys.stdin) if args.follow else None   # reading starts now: nothing typed is lost
    gen = _load_generator(args)
    if args.follow and not gen.endless:
        raise UsageError(f"--follow needs a bundle trained for endless streams; {gen.bundle.path} has no "
                         f"'streaming' section in its manifest")
    with _warnings_as_lines():
        frames = gen.stream(args.text, seconds=args.seconds, seed=args.seed, align=align,
                            sampling=_sampling(args, gen.sampling_defaults))
    if frames.aligned_text is not None:
        print(f"mogo: {'aligned prompt' if align else 'actions'}: {frames.aligned_text!r}", file=sys.stderr, flush=True)
    out = sys.stdout
    arrived = False
    try:
        for f in frames:
            request = _pending(requests)
            if request is not None:
                with _warnings_as_lines():
                    request.apply(frames, align=align)
                event = {"event": "prompt" if request.control is None else "control", "token": frames.tokens,
                         "frame": f.index}
                if request.prompt is not None:
                    event.update(text=request.prompt, **({"aligned": frames.aligned_text}
                                                         if frames.aligned_text is not None else {}))
                if request.control is not None:
                    event["request"] = {k: (f"{len(v)} points" if k == "path" else v) for k, v in request.control.items()}
                    arrived = False
                out.write(json.dumps(event) + "\n")
            if frames.arrived and not arrived:      # a goal or a path's end reached: said once
                arrived = True
                out.write(json.dumps({"event": "arrived", "token": frames.tokens, "frame": f.index}) + "\n")
            joints = [[round(float(c), JOINT_DECIMALS) for c in j] for j in f.joints]
            out.write(json.dumps({"frame": f.index, "time": round(f.time, 6), "joints": joints},
                                 separators=(",", ":")) + "\n")
            out.flush()                   # a game reads the pipe frame by frame
    except BrokenPipeError:
        # The reader closed the pipe: it has what it wanted. Point stdout at devnull so the interpreter's
        # final flush does not raise again.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, out.fileno())
        os.close(devnull)
    return 0


def _read_lines(stream) -> queue.Queue:
    """Lines of `stream` as they arrive, read by a daemon thread, so frames keep flowing while stdin is quiet.

    A real stdin is read as bytes and decoded with surrogateescape: a line that is not UTF-8 then reaches the prompt
    check (`mogo: error:`) instead of killing this thread with a traceback, as a strict decoder would."""
    lines: queue.Queue = queue.Queue()

    def read():
        raw = getattr(stream, "buffer", stream)
        try:
            while line := raw.readline(MAX_LINE_BYTES + 1):
                if len(line) > MAX_LINE_BYTES:   # read no further: a line without end would fill the memory
                    lines.put(UsageError(f"stdin: a line longer than {MAX_LINE_BYTES:,} bytes; a prompt has at most "
                                         f"{MAX_PROMPT_CHARS:,} characters"))
                    return
                if isinstance(line, bytes):
                    line = line.decode("utf-8", "surrogateescape")
                lines.put(line.rstrip("\r\n"))     # bytes keep the "\r" of a Windows line end
        except (OSError, ValueError) as e:
            lines.put(UsageError(f"stdin: cannot read it ({e})"))

    threading.Thread(target=read, daemon=True).start()
    return lines


def _pending(lines: queue.Queue | None) -> Request | None:
    """The requests that came in since the last look, parsed (a bad one ends the stream with its message) and
    folded into one: a game that writes faster than the stream steps gets its newest prompt and its newest control
    followed, not a backlog."""
    prompt = control = None
    while lines is not None and not lines.empty():
        line = lines.get_nowait()
        if isinstance(line, Exception):
            raise line
        if line.strip():
            try:
                request = parse_request(line)
            except ValueError as e:
                raise UsageError(f"stdin: {e}") from None
            prompt = request.prompt if request.prompt is not None else prompt
            control = request.control if request.control is not None else control
    return Request(prompt, control) if prompt is not None or control is not None else None


def cmd_info(args) -> int:
    path = args.bundle if args.bundle is not None else default_bundle()[0]
    bundle = Bundle(path, read_manifest(path))       # each file's size and sha256 are checked below, one by one
    m, d = bundle.manifest, bundle.dims
    producer = m.producer or {}
    made = {k: producer[k] for k in ("name", "version", "torch", "onnx", "onnxruntime", "opset", "created")
            if k in producer}
    print(f"bundle     {bundle.path.resolve()}")
    print(f"schema     mogo-bundle v{SCHEMA_VERSION}; producer {_describe(made)}")
    print(f"model      levels {d.num_levels}, codebook {d.codebook_size}, layers {d.n_layers}, "
          f"heads {d.n_heads} x {d.head_dim}, text_dim {d.text_dim}, latent_dim {d.latent_dim}")
    print(f"motion     {d.fps:g} fps, {d.downsample} frames/token, receptive field {d.receptive_field} tokens, "
          f"max {d.max_tokens} tokens ({d.max_seconds:g} s)")
    print(f"skeleton   {bundle.skeleton.name}, {bundle.skeleton.num_joints} joints, {d.feature_dim} features")
    te = m.text_encoder
    print(f"text       {te.name}, max_length {te.max_length}, pooling {te.pooling}")
    print(f"sampling   {_describe(m.sampling_defaults.to_dict())}")
    print("variants")
    for v in bundle.variants:
        files = [m.graph_file(g, v).file for g in m.graph_names]
        print(f"  {v:<12} {_mb(bundle.total_bytes(v)):>9}  " + ", ".join(f"{g}={f}" for g, f in zip(m.graph_names, files)))
    if m.portable:
        print(f"portable   step graph over a fixed cache of {m.portable.capacity} steps, opset {m.portable.opset}")
    if m.ort:
        print(f"ort        {', '.join(m.ort.variants)} for an onnxruntime {m.ort.onnxruntime} minimal build: "
              f"operators in {m.ort.required_operators}")
    print("files")
    failed = []
    for name, (size, digest) in m.files.items():
        try:
            bundle.read_verified(name)
        except BundleError:
            failed.append(name)
        print(f"  {name:<28} {_mb(size):>9}  sha256 {digest[:16]}  {'FAILED' if name in failed else 'OK'}")
    if failed:
        raise BundleError(f"{bundle.path}: {len(failed)} file(s) missing or not matching their size and sha256 in "
                          f"manifest.json: {', '.join(failed)} (corrupted or replaced; re-export or re-copy the "
                          f"bundle)")
    try:   # its hash says it is the exporter's file, not that this runtime can read it
        load_tokenizer(bundle.read_verified(te.tokenizer), str(bundle.path / te.tokenizer))
    except ValueError as e:
        raise BundleError(str(e)) from None
    print(f"tokenizer  {te.tokenizer} reads (cut at {te.max_length} tokens)")
    bundle.check_graph_signatures()
    print("graphs     inputs and outputs match the manifest")
    return 0


def _describe(d: dict) -> str:
    return ", ".join(f"{k} {v}" for k, v in d.items()) or "(none)"


def _mb(n: int) -> str:
    return f"{n / 1e6:.2f} MB" if n >= 10_000 else f"{n} B"


if __name__ == "__main__":
    sys.exit(main())
