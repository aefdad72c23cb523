"""The fuzz suite: seeded random calls of the public API (`generate`, `stream`), the `mogo` command line, hostile
rig files (`--rig FILE`, `Motion.save(..., rig=FILE)`), hostile stdin of `mogo stream --follow`, and `Bundle.load`
on corrupt bundles, each in a worker process with a time bound, sorted by outcome.

    python tests/fuzz.py --cases 10000 [--seed 0] [--strace]     # `make fuzz`
    python tests/fuzz.py --cases 300                              # what tests/runtime/test_fuzz.py runs in CI

Outcomes: ok (a finite motion, or exit 0 with its files), refused (ValueError / BundleError with a message; CLI:
exit 2 and one "mogo: error:" line), and the failures: crash (any other exception, a traceback, an error that names
nothing), nonfinite (NaN or inf came back), hang (over the time bound), outside (a file outside the bundle, Python
and its packages was opened: Python's audit hook, and with --strace every open the process makes, C++ included).
The exit status is 1 if any case failed. Cases are reproducible from (seed, index): `--only INDEX` reruns one.
"""
from __future__ import annotations

import argparse
import collections
import io
import json
import os
import select
import shutil
import subprocess
import sys
import tempfile
import time
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE / "runtime"), str(HERE)]
TIME_LIMIT_S = 30.0
FAILURES = ("crash", "nonfinite", "hang", "outside")

TEXTS = ["a person walks forward", "", " ", "\n", "a" * 100_000, "walk " * 5000, "\ud800", "\x00", "\u202e\u0301" * 50,
         "🙂" * 300, "a person\tjumps\r\nand\x1b[31m", "../../etc/passwd", "%s%n{0}", 42, None, b"bytes", ["a", "b"],
         [], ["a person walks"] * 70, [("a person walks", 0.0), ("a person jumps", 2.0)], [("x", -1.0)], [("x", "y")]]
NUMBERS = [None, 0, 1, 2, -1, 0.5, 1e-9, 600, 10 ** 6, 1e308, -1e308, float("nan"), float("inf"), True, False, "3",
           np.float32(2.0), np.int64(3), np.float64(1e300), [1], 2 ** 63, -(2 ** 63)]
VARIANTS = ["fp32", "int8", "", "FP32", "../fp32", None, 3]


def _pick(rng, pool):
    return pool[rng.integers(len(pool))]


# ----------------------------------------------------------------------------------------------- cases

VALID = {"seconds": [None, 0.5, 1, 2.5], "seed": [0, 1, 12345], "temperature": [0, 0.7, 1.0], "top_k": [0, 1, 5],
         "top_p": [0.5, 0.9, 1.0], "guidance": [1.0, 2.0], "text": ["a person walks forward", "a person jumps twice",
                                                                  ["a person walks", "a person runs"]]}


def api_case(rng) -> dict:
    """A call that is valid but for 0 to 3 hostile arguments."""
    case = {"kind": "api", "call": _pick(rng, ["generate", "stream"]), "text": _pick(rng, VALID["text"][:2]),
            "kwargs": {k: _pick(rng, VALID[k]) for k in ("seconds", "seed")},
            "sampling": {k: _pick(rng, VALID[k]) for k in ("temperature", "top_k", "top_p", "guidance")
                         if rng.random() < 0.5},
            "variant": _pick(rng, ["fp32", "int8"]), "threads": 1, "chunk": 4}
    if case["call"] == "generate" and rng.random() < 0.3:
        case["text"] = _pick(rng, VALID["text"])
    for _ in range(rng.integers(4)):
        field = _pick(rng, ["text", "seconds", "seed", "temperature", "top_k", "top_p", "guidance", "align", "variant",
                            "threads", "chunk"])
        if field == "text":
            case["text"] = _pick(rng, TEXTS)
        elif field in ("seconds", "seed"):
            case["kwargs"][field] = _pick(rng, NUMBERS)
        elif field == "align":
            case["kwargs"]["align"] = _pick(rng, [True, False, None, "yes", 1])
        elif field == "variant":
            case["variant"] = _pick(rng, VARIANTS)
        elif field == "threads":
            case["threads"] = _pick(rng, [2, 0, -1, 10 ** 6, 1.5, True, "2", np.int64(1)])
        elif field == "chunk":
            case["chunk"] = _pick(rng, [1, 0, -3, 10 ** 9, 2.5, None, np.int32(2)])
        else:
            case["sampling"][field] = _pick(rng, NUMBERS)
    return case


def cli_case(rng) -> dict:
    argv = [_pick(rng, ["generate", "stream", "info", "rigs", "crowd", "dance", ""])]
    if argv[0] == "crowd":       # sizes: a crowd is bounded by the memory available
        return {"kind": "cli", "argv": ["crowd", "a person walks", "-n", _pick(rng, ["1", "3", "2000", "-1", "x",
                                                                                      "1e9", "4000000"]),
                                        "--seconds", _pick(rng, ["0.2", "1", "0", "x"]), "--variant",
                                        _pick(rng, ["int8_fixed", "portable", "fp32"]), "-o", "OUT/crowd"]}
    if argv[0] in ("generate", "stream"):
        text = _pick(rng, TEXTS[:14])
        argv.append(text if isinstance(text, str) else str(text))
    for flag, pool in (("--seconds", ["1", "0", "-1", "1e308", "nan", "inf", "x", "600"]),
                       ("--seed", ["0", "-1", "1.5", "99999999999999999999999", "x"]),
                       ("--temperature", ["0", "1", "-1", "inf", "nan"]), ("--top-p", ["0", "0.9", "2"]),
                       ("--top-k", ["0", "5", "-5"]), ("--guidance", ["1", "2", "-3", "1e308"]),
                       ("--threads", ["1", "0", "1000000", "x"]), ("--variant", ["fp32", "int8", "", "nope"]),
                       ("--rig", ["mixamo", "ue5", "nope", "../x.json", "/dev/zero.json"])):
        if rng.random() < 0.25:
            argv += [flag, _pick(rng, pool)]
    if argv[0] == "generate" and rng.random() < 0.9:
        for _ in range(rng.integers(1, 3)):
            argv += ["-o", "OUT/" + _pick(rng, ["x.bvh", "x.glb", "x.json", "x.npy", "x.gif", "x.fbx", "", "dir/"])]
    if rng.random() < 0.1:
        argv.append(_pick(rng, ["--in-place", "--align", "--no-align", "--int8", "--follow", "--bogus"]))
    return {"kind": "cli", "argv": argv}


def rig_case(rng) -> dict:
    """A rig file a user could hand `--rig`: a shipped rig with a field broken, or a file that is no rig at all."""
    how = _pick(rng, ["leaf", "leaf", "delete", "nesting", "huge", "binary", "device", "fifo", "empty"])
    return {"kind": "rig", "how": how, "rig": _pick(rng, ["mixamo", "ue5", "unity", "vrm"]),
            "state": int(rng.integers(2 ** 63))}


def stdin_case(rng) -> dict:
    """`mogo stream --follow` with what a game (or a broken pipe) might write to its stdin."""
    lines = [_pick(rng, TEXTS[:14]) for _ in range(rng.integers(0, 5))]
    how = _pick(rng, ["lines", "lines", "flood", "no newline", "huge line", "binary", "closed", "crlf", "json",
                      "control"])
    if how == "control":        # requests where to go (docs/bundle.md, "Control"), each field hostile or not
        lines = [json.dumps({k: _pick(rng, pool) for k, pool in _pick(rng, CONTROL_REQUESTS).items()
                             if rng.random() < 0.9}, default=str) for _ in range(rng.integers(1, 5))]
    return {"kind": "stdin", "how": how, "lines": [t if isinstance(t, str) else str(t) for t in lines],
            "size": int(rng.integers(1, 200_000))}


POINTS = [[1.0, 2.0], [0, 0], [1e308, 0], [-1e7, 3], ["1", 2], [True, 0], [1, 2, 3], [], None, "there", [[1, 2]], 5]
CONTROL_REQUESTS = [  # field -> values a game (or an attacker) might send; json.dumps writes nan/inf as NaN/Infinity
    {"goal": POINTS, "speed": [1.3, 0, -1, 0.05, 10, 11, float("nan"), "fast", None, 1e308], "prompt": TEXTS[:6]},
    {"path": [[[0, 0], [1, 1]], [[0, 0]], [[0, 0], [0, 0]], [[0, 0], [float("inf"), 1]], [[i, i % 3] for i in
              range(3000)], [[0, 0], ["a", 1]], [[[0, 0]]], "path", {}], "speed": [2.5, 0.01, 99]},
    {"velocity": POINTS, "facing": POINTS + [[0, 0]]},
    {"root": [[1, 2, 0.5], [1, 2], [0, 0, float("nan")], [0, 0, 1e9], ["a", 0, 0], [[0, 0], 0, 0]]},
    {"release": [True, False, 1, "yes", None]},
    {"gaol": [[1, 2]], "prompt": ["a person walks"]},
]


def _rig_file(case: dict, out: Path) -> Path:
    from mogo_runtime.outputs.rig import load_rig
    import corrupt
    path, rng = out / "rig.json", np.random.default_rng(case["state"])
    data = load_rig(case["rig"]).to_dict()
    how = case["how"]
    if how in ("leaf", "delete"):
        paths = [p for p, _ in corrupt.leaves(data) if p]
        at = paths[rng.integers(len(paths))]
        pool = [None, True, 0, -1, 1e308, float("nan"), "", "x" * 10_000, ["x"], {}, [[[]]], "pelvis", "mixamorig:Hips"]
        corrupt.delete_at(data, at) if how == "delete" else corrupt.set_at(data, at, pool[rng.integers(len(pool))])
        path.write_text(json.dumps(data))
    elif how == "nesting":
        path.write_text("[" * int(rng.integers(1000, 400_000)))
    elif how == "huge":
        path.write_bytes(b" " * (2 << 20) + json.dumps(data).encode())
    elif how == "binary":
        path.write_bytes(os.urandom(int(rng.integers(1, 5000))))
    elif how == "device":
        path.symlink_to("/dev/zero")
    elif how == "fifo":
        os.mkfifo(path)
    else:
        path.write_bytes(b"")
    return path


def _stdin_bytes(case: dict) -> bytes | None:
    how, lines = case["how"], case["lines"]
    if how == "closed":
        return None
    if how == "flood":
        return "".join(f"a person walks {i}\n" for i in range(case["size"] // 10)).encode()
    if how == "no newline":
        return b"\0" * (case["size"] * 5)
    if how == "huge line":
        return ("a person walks " * (case["size"] // 5) + "\n").encode()
    if how == "binary":
        return os.urandom(case["size"])
    end = "\r\n" if how == "crlf" else "\n"
    body = [json.dumps({"prompt": t}) for t in lines] if how == "json" else lines
    return "".join(t + end for t in body).encode("utf-8", "surrogateescape")


# ----------------------------------------------------------------------------------------------- the worker

def _run_api(case: dict, bundle: Path) -> tuple[str, str]:
    from mogo_runtime import MotionGenerator, SamplingConfig
    gen = MotionGenerator(bundle, variant=case["variant"], threads=case["threads"])
    kwargs = dict(case["kwargs"])
    if case["sampling"]:
        kwargs["sampling"] = SamplingConfig(**case["sampling"])
    if case["call"] == "generate":
        motion = gen.generate(case["text"], **kwargs)
        joints = [m.joints for m in (motion if isinstance(motion, list) else [motion])]   # a batch gives a list
    else:
        if "seconds" not in kwargs or kwargs["seconds"] is None:
            kwargs["seconds"] = 2                 # an endless stream would never end the case
        stream = gen.stream(case["text"], chunk=case["chunk"], **kwargs)
        joints = [f.joints for f, _ in zip(stream, range(2000))]
    if not all(np.isfinite(j).all() for j in joints):
        return "nonfinite", "NaN or inf joints"
    return "ok", ""


def _run_rig(case: dict, bundle: Path, out: Path) -> tuple[str, str]:
    """The rig through the command (`generate --rig`), as a user hands it over: refused in one line, or written."""
    rig = _rig_file(case, out)
    return _run_cli({"argv": ["generate", "a person walks forward", "--seconds", "1", "-o", "OUT/x.glb", "-o",
                              "OUT/x.bvh", "--rig", str(rig)]}, bundle, out)


def _run_cli(case: dict, bundle: Path, out: Path, stdin: bytes | None = b"") -> tuple[str, str]:
    from mogo_runtime.cli import main
    argv = [a.replace("OUT/", f"{out}/") for a in case["argv"]]
    if argv[0] in ("generate", "stream", "crowd") and "--bundle" not in argv:
        argv += ["--bundle", str(bundle)]
    if argv[0] == "info":            # not the default bundle folder of the working directory
        argv.append(str(bundle))
    if argv[0] == "stream" and "--seconds" not in argv:
        argv += ["--seconds", "1"]
    err, sink = io.StringIO(), io.StringIO()
    # `stream --follow` reads prompts from stdin: the case's bytes, or none at all (a closed stdin is None)
    stdin, sys.stdin = sys.stdin, None if stdin is None else io.TextIOWrapper(io.BytesIO(stdin))
    try:
        with redirect_stderr(err), redirect_stdout(sink):
            code = main(argv)
    except SystemExit as e:          # argparse's own exits (--help)
        code = e.code
    finally:
        sys.stdin = stdin
    text = err.getvalue()
    if "Traceback" in text:
        return "crash", f"traceback: {text[-300:]}"
    if code == 0:
        return "ok", ""
    errors = [l for l in text.splitlines() if l.startswith("mogo: error:")]
    if code == 2 and len(errors) == 1:
        return "refused", errors[0]
    return "crash", f"exit {code}, stderr {text[-300:]!r}"


def _run_bundle(case: dict, good: Path, work: Path) -> tuple[str, str]:
    import corrupt
    graphs = sorted(n for n in corrupt.read_manifest(good)["files"] if n.endswith(".onnx"))
    rng = np.random.default_rng(case["state"])
    name, mutate = corrupt.random_case(corrupt.read_manifest(good), rng, graphs)
    result, detail, _ = corrupt.run_case(good, work / "b", mutate, TIME_LIMIT_S)
    return result, f"{name}: {detail}"


def worker(good: Path, work: Path) -> None:
    """Read case JSON lines on stdin, answer one result JSON line per case on stdout."""
    import corrupt
    from mogo_runtime import BundleError
    allowed = corrupt.allowed_folders(work)
    # answers go on a private copy of stdout; fd 1 itself points at stderr, so a line some library writes
    # there from C (past redirect_stdout) cannot corrupt the driver's JSON
    answers = os.fdopen(os.dup(1), "w")
    os.dup2(2, 1)
    for line in sys.stdin:
        case = _decode(json.loads(line))
        out = work / "out"
        shutil.rmtree(out, ignore_errors=True)
        out.mkdir(parents=True)
        start = time.perf_counter()
        if case["kind"] == "bundle":
            result, detail = _run_bundle(case, good, work)
        else:
            corrupt._AUDIT = corrupt._AUDIT or corrupt._OutsideReads()
            # a rig file the command line names is the user's own: reading it, wherever it is, is what was asked
            named = [a for flag, a in zip(case.get("argv", []), case.get("argv", [])[1:]) if flag == "--rig"]
            corrupt._AUDIT.allowed = [os.path.realpath(a) for a in allowed + [good] + named]
            corrupt._AUDIT.seen = []
            try:
                if case["kind"] == "api":
                    result, detail = _run_api(case, good)
                elif case["kind"] == "rig":
                    result, detail = _run_rig(case, good, out)
                elif case["kind"] == "stdin":
                    result, detail = _run_cli({"argv": ["stream", "a person walks forward", "--follow", "--seconds",
                                                        "1"]}, good, out, _stdin_bytes(case))
                else:
                    result, detail = _run_cli(case, good, out)
            except (BundleError, ValueError) as e:
                result, detail = ("refused", str(e)) if str(e) else ("crash", f"{type(e).__name__} with no message")
            except Exception as e:   # noqa: BLE001
                result, detail = "crash", f"{type(e).__name__}: {str(e)[:300]}"
            finally:
                corrupt._AUDIT.allowed = []
            if corrupt._AUDIT.seen:
                result, detail = "outside", f"opened {corrupt._AUDIT.seen[0]}"
        print(json.dumps({"result": result, "detail": detail[:500], "seconds": time.perf_counter() - start}),
              file=answers, flush=True)


# ----------------------------------------------------------------------------------------------- the driver

def make_cases(n: int, seed: int) -> list[dict]:
    rng = np.random.default_rng(seed)
    kinds = rng.choice(5, size=n, p=[0.3, 0.2, 0.3, 0.1, 0.1])
    return [(api_case, cli_case, lambda r: {"kind": "bundle", "state": int(r.integers(2 ** 63))}, rig_case,
             stdin_case)[k](rng) for k in kinds]


def _jsonable(case: dict) -> str:
    def enc(o):
        if isinstance(o, np.generic):
            return {"__np__": type(o).__name__, "v": o.item()}
        if isinstance(o, bytes):
            return {"__bytes__": o.decode("latin-1")}
        if isinstance(o, tuple):
            return list(o)
        raise TypeError(type(o))
    return json.dumps(case, default=enc, ensure_ascii=True)


def _decode(obj):
    if isinstance(obj, dict):
        if "__np__" in obj:
            return getattr(np, obj["__np__"])(obj["v"])
        if "__bytes__" in obj:
            return obj["__bytes__"].encode("latin-1")
        return {k: _decode(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_decode(v) for v in obj]
    return obj


def run(cases: list[dict], good: Path, strace: bool = False, progress=None) -> list[dict]:
    """Run `cases` in a worker process (restarted after a hang); -> one result dict per case."""
    results: list[dict] = []
    work = Path(tempfile.mkdtemp(prefix="mogo-fuzz-"))
    trace = work / "strace"
    try:
        i = 0
        while i < len(cases):
            cmd = [sys.executable, __file__, "--worker", str(good), str(work)]
            if strace:
                cmd = ["strace", "-f", "-qq", "-e", "trace=open,openat,openat2", "-o", str(trace), *cmd]
            proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
            while i < len(cases):
                proc.stdin.write(_jsonable(cases[i]) + "\n")
                proc.stdin.flush()
                ready, _, _ = select.select([proc.stdout], [], [], TIME_LIMIT_S * 2)
                line = proc.stdout.readline() if ready else ""
                if not line:
                    proc.kill()
                    proc.wait()
                    results.append({"result": "hang" if not ready else "crash",
                                    "detail": "no answer in time" if not ready else f"worker died ({proc.returncode})",
                                    "seconds": TIME_LIMIT_S * 2})
                    i += 1
                    break
                try:
                    results.append(json.loads(line))
                except json.JSONDecodeError:
                    results.append({"result": "crash", "detail": f"the worker answered {line[:200]!r}", "seconds": 0})
                i += 1
                if progress and (i % 100 == 0 or i == len(cases)):
                    progress(i)
            else:
                proc.stdin.close()
                proc.wait()
            if strace and trace.exists():
                _strace_check(trace, good, work, results)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    for case, r in zip(cases, results):
        r["case"] = case
    return results


def _strace_check(trace: Path, good: Path, work: Path, results: list[dict]) -> None:
    """Every path the worker process tree opened must be under an allowed folder (C++ opens included)."""
    import corrupt
    allowed = [os.path.realpath(a) for a in corrupt.allowed_folders(work) + [good, HERE.parent, "/tmp"]]
    allowed += ["/etc/ld.so.cache", "/lib", "/usr/lib", "/lib64", "/usr/lib64", "/usr/share/zoneinfo", "/etc/localtime",
                "/usr/share/locale", "/etc/locale.alias",
                "/etc/os-release", "/etc/lsb-release", "/.dockerenv",      # onnxruntime's platform check at import
                # onnxruntime 1.32's telemetry store (a SQLite file it opens with every environment, even after
                # disable_telemetry_events(); measured with strace): not a bundle file, and nothing mogo can turn off
                os.path.expanduser("~/.cache/Microsoft/DeveloperTools"), "/var/tmp/etilqs_*",   # and its SQLite temps
                # name resolution, for --rewriter-url (a chat endpoint the user named)
                "/etc/hosts", "/etc/host.conf", "/etc/nsswitch.conf", "/etc/resolv.conf", "/etc/gai.conf", "/etc/ssl"]
    outside, pending = set(), {}
    for line in trace.read_text(errors="replace").splitlines():
        pid = line.split(" ", 1)[0]
        if "<unfinished ...>" in line and '"' in line:     # a call interrupted by another thread's: its end follows
            pending[pid] = line
            continue
        if "resumed>" in line and pid in pending:
            line = pending.pop(pid) + line
        if '"' not in line or "ENOENT" in line:
            continue
        path = os.path.realpath(line.split('"')[1])
        if not any(path == a or path.startswith(a.rstrip("/") + "/") or a.endswith("*") and path.startswith(a[:-1])
                   for a in allowed):
            outside.add(path)
    trace.unlink()
    if outside:
        results.append({"result": "outside", "detail": f"strace: opened {sorted(outside)[:5]}", "seconds": 0.0,
                        "case": {"kind": "strace"}})


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, default=10_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only", type=int, help="rerun case INDEX of this seed")
    ap.add_argument("--strace", action="store_true", help="also record every open() with strace")
    ap.add_argument("--bundle", type=Path, help="a good bundle to fuzz (default: a fresh toy bundle)")
    ap.add_argument("--json", type=Path, help="write every result here")
    ap.add_argument("--worker", nargs=2, type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        worker(*args.worker)
        return 0
    cases = make_cases(args.cases, args.seed)
    if args.only is not None:
        cases = [cases[args.only]]
    good = args.bundle
    tmp = None
    if good is None:
        from toy_bundle import build_toy_bundle
        tmp = Path(tempfile.mkdtemp(prefix="mogo-fuzz-bundle-"))
        mean = np.load(HERE.parents[1] / "shared" / "fixtures" / "humanml3d" / "Mean.npy")
        good = build_toy_bundle(tmp / "toy", mean, portable=True)     # portable: crowds too
    start = time.perf_counter()
    try:
        results = run(cases, good, args.strace,
                      progress=lambda i: print(f"\rfuzz: {i}/{len(cases)}", end="", file=sys.stderr, flush=True))
    finally:
        if tmp:
            shutil.rmtree(tmp, ignore_errors=True)
    print(file=sys.stderr)
    counts = collections.Counter((r["case"]["kind"], r["result"]) for r in results)
    kinds = sorted({k for k, _ in counts})
    print(f"{len(cases)} cases (seed {args.seed}) in {time.perf_counter() - start:.0f} s")
    for k in kinds:
        print(f"  {k:7s} " + ", ".join(f"{res} {counts[k, res]}" for res in ("ok", "refused", *FAILURES)))
    failed = [r for r in results if r["result"] in FAILURES]
    for r in failed[:20]:
        print(f"FAIL {r['result']}: {r['detail'][:300]}\n     case {str(r['case'])[:300]}")
    if args.json:
        args.json.write_text(json.dumps(results, default=str))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
