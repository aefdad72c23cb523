"""Corrupt and hostile bundles, built from a good one: the cases tests/runtime/test_corrupt_bundles.py runs (a fixed
list) and `make fuzz` draws from (seeded random mutations). Each case is a function that damages a copy of the
bundle folder; `outcome` then loads it, generates from it and classifies what happened.

Outcomes: "ok" (a finite motion came back), "refused" (BundleError or ValueError that names the file, field or
value), "crash" (any other exception, or a refusal that names nothing), "nonfinite" (NaN or inf joints came back),
"outside" (a file outside the bundle folder was opened).
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

from mogo_runtime import Bundle, BundleError, MotionGenerator

Case = Callable[[Path], None]


# ----------------------------------------------------------------------------------------------- helpers

def read_manifest(folder: Path) -> dict:
    return json.loads((folder / "manifest.json").read_text())


def write_manifest(folder: Path, m: dict) -> None:
    (folder / "manifest.json").write_text(json.dumps(m))


def rehash(folder: Path, name: str) -> None:
    """Record `name`'s current size and sha256 in the manifest, as a careful forger would."""
    m = read_manifest(folder)
    data = (folder / name).read_bytes()
    m["files"][name] = {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
    write_manifest(folder, m)


def leaves(obj, path=()):
    """Every (path, value) of a JSON tree."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from leaves(v, path + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from leaves(v, path + (i,))
    yield path, obj


def set_at(obj, path, value):
    for k in path[:-1]:
        obj = obj[k]
    obj[path[-1]] = value


def delete_at(obj, path):
    for k in path[:-1]:
        obj = obj[k]
    del obj[path[-1]]


# ----------------------------------------------------------------------------------------------- cases

def manifest_edit(fn) -> Case:
    def case(folder: Path) -> None:
        m = read_manifest(folder)
        fn(m)
        write_manifest(folder, m)
    return case


def raw_manifest(text: bytes) -> Case:
    return lambda folder: (folder / "manifest.json").write_bytes(text)


def file_bytes(name: str, transform, forge: bool) -> Case:
    def case(folder: Path) -> None:
        p = folder / name
        p.write_bytes(transform(p.read_bytes()))
        if forge:
            rehash(folder, name)
    return case


def replace_path(name: str, make) -> Case:
    def case(folder: Path) -> None:
        p = folder / name
        p.unlink()
        make(folder, p)
    return case


def outside_symlink(folder: Path, p: Path) -> None:
    target = folder.parent / f"{folder.name}-outside-{p.name}"
    shutil.copy(str(p.with_name("manifest.json")), target)   # any file; the point is where it lives
    p.symlink_to(target)


def rename_listed(old: str, new: str) -> Case:
    """List file `old` under the name `new` (its bytes moved there if `new` is inside the folder)."""
    def case(folder: Path) -> None:
        m = read_manifest(folder)
        m["files"][new] = m["files"].pop(old)
        for graphs in m["variants"].values():
            for entry in graphs.values():
                if entry["file"] == old:
                    entry["file"] = new
        if m["text_encoder"]["tokenizer"] == old:
            m["text_encoder"]["tokenizer"] = new
        write_manifest(folder, m)
    return case


def swap_files(a: str, b: str) -> Case:
    def case(folder: Path) -> None:
        pa, pb = folder / a, folder / b
        da, db = pa.read_bytes(), pb.read_bytes()
        pa.write_bytes(db)
        pb.write_bytes(da)
        rehash(folder, a)
        rehash(folder, b)
    return case


def nan_weights(name: str) -> Case:
    """Every float initializer of a graph set to NaN, the manifest's hash recomputed: a valid, hostile graph."""
    def case(folder: Path) -> None:
        import onnx
        from onnx import numpy_helper
        model = onnx.load(str(folder / name))
        for init in model.graph.initializer:
            a = numpy_helper.to_array(init)
            if a.dtype.kind == "f":
                init.CopyFrom(numpy_helper.from_array(np.full_like(a, np.nan), init.name))
        onnx.save(model, str(folder / name))
        rehash(folder, name)
    return case


def external_data(name: str, outside: bool) -> Case:
    """The graph's weights moved to an external-data file, inside the folder or (paths patched in the proto, as
    the onnx package refuses to write them) outside it; the graph's hash forged."""
    def case(folder: Path) -> None:
        import onnx
        model = onnx.load(str(folder / name))
        data = name + ".data"
        onnx.save_model(model, str(folder / name), save_as_external_data=True, all_tensors_to_one_file=True,
                        location=data, size_threshold=0)
        if outside:
            (folder / data).rename(folder.parent / data)
            model = onnx.load(str(folder / name), load_external_data=False)
            for init in model.graph.initializer:
                for entry in init.external_data:
                    if entry.key == "location":
                        entry.value = "../" + data
            onnx.save(model, str(folder / name))
        rehash(folder, name)
    return case


def graph_edit(name: str, edit) -> Case:
    """`edit(graph)` applied to a graph's proto, the manifest's hash recomputed: a graph that loads and then lies."""
    def case(folder: Path) -> None:
        import onnx
        model = onnx.load(str(folder / name))
        edit(model.graph)
        onnx.save(model, str(folder / name))
        rehash(folder, name)
    return case


def doubled_presents(g) -> None:
    """present = concat(present, present): a step whose cache is twice as long as it should be, every step."""
    import onnx
    for out in g.output:
        if out.name.startswith("present."):
            inner = out.name + ".inner"
            for node in g.node:
                node.output[:] = [inner if o == out.name else o for o in node.output]
            g.node.append(onnx.helper.make_node("Concat", [inner, inner], [out.name], axis=2))


def failing_reshape(g) -> None:
    """The first output reshaped to one row more than it has along axis 1: loads, fails only when run."""
    import onnx
    out, h, T = g.output[0].name, onnx.helper, onnx.TensorProto.INT64
    for node in g.node:
        node.output[:] = [out + ".inner" if o == out else o for o in node.output]
    width = [d.dim_value for d in g.output[0].type.tensor_type.shape.dim][-1]
    g.initializer.extend([h.make_tensor(n, T, [1], [v]) for n, v in (("k0", 0), ("k1", 1), ("k2", 2),
                                                                      ("width", width))])
    g.node.extend([h.make_node("Shape", [out + ".inner"], ["shape"]), h.make_node("Slice", ["shape", "k0", "k1"], ["b"]),
                   h.make_node("Slice", ["shape", "k1", "k2"], ["n"]), h.make_node("Add", ["n", "k1"], ["n1"]),
                   h.make_node("Concat", ["b", "n1", "width"], ["new_shape"], axis=0),
                   h.make_node("Reshape", [out + ".inner", "new_shape"], [out])])


def tokenizer_part(part: str, spec) -> Case:
    """tokenizer.json with one part (normalizer, pre_tokenizer, model) replaced, its hash recomputed."""
    def case(folder: Path) -> None:
        tok = json.loads((folder / "tokenizer.json").read_text())
        tok[part] = spec
        (folder / "tokenizer.json").write_text(json.dumps(tok))
        rehash(folder, "tokenizer.json")
    return case


def manifest_link(target) -> Case:
    """manifest.json replaced by a link: to a manifest elsewhere (valid), or to `target(folder)`."""
    def case(folder: Path) -> None:
        aside = folder.parent / "manifest-aside.json"
        (folder / "manifest.json").rename(aside)
        (folder / "manifest.json").symlink_to(target(folder) if target else aside)
    return case


def sparse_graph(name: str, size: int) -> Case:
    def case(folder: Path) -> None:
        p = folder / name
        with open(p, "wb") as f:
            f.truncate(size)
        m = read_manifest(folder)
        m["files"][name]["bytes"] = size
        write_manifest(folder, m)
    return case


def fixed_cases(folder: Path) -> dict[str, Case]:
    """The named cases the CI test runs, for a good bundle at `folder` (its manifest decides the field list)."""
    m = read_manifest(folder)
    graphs = sorted(n for n in m["files"] if n.endswith(".onnx"))
    cases: dict[str, Case] = {
        "manifest: empty": raw_manifest(b""),
        "manifest: truncated": lambda f: (f / "manifest.json").write_bytes((f / "manifest.json").read_bytes()[:500]),
        "manifest: not utf-8": raw_manifest(b"\xff\xfe{}"),
        "manifest: deeply nested": raw_manifest(b"[" * 100000 + b"]" * 100000),
        "manifest: a list": raw_manifest(b"[]"),
        "manifest: huge number": manifest_edit(lambda m: set_at(m, ("model", "max_tokens"), 10 ** 400)),
        "manifest: NaN": manifest_edit(lambda m: set_at(m, ("model", "fps"), float("nan"))),
        "manifest: 20 MB": raw_manifest(b" " * (20 << 20)),
        "model.max_tokens 0": manifest_edit(lambda m: set_at(m, ("model", "max_tokens"), 0)),
        "model.fps -20": manifest_edit(lambda m: set_at(m, ("model", "fps"), -20)),
        "model.downsample 3": manifest_edit(lambda m: set_at(m, ("model", "downsample"), 3)),
        "model.codebook_size 0": manifest_edit(lambda m: set_at(m, ("model", "codebook_size"), 0)),
        "model.num_levels 0": manifest_edit(lambda m: set_at(m, ("model", "num_levels"), 0)),
        "model.n_heads 0": manifest_edit(lambda m: set_at(m, ("model", "n_heads"), 0)),
        "model.receptive_field 0": manifest_edit(lambda m: set_at(m, ("model", "receptive_field"), 0)),
        "normalization.std zeros": manifest_edit(lambda m: set_at(m, ("normalization", "std"),
                                                                  [0.0] * len(m["normalization"]["std"]))),
        "normalization.mean short": manifest_edit(lambda m: set_at(m, ("normalization", "mean"), [0.0])),
        "skeleton.parents cycle": manifest_edit(lambda m: set_at(m, ("skeleton", "parents", 0), 1)),
        "skeleton.parents out of range": manifest_edit(lambda m: set_at(m, ("skeleton", "parents", 3), 99)),
        "skeleton.fps 0": manifest_edit(lambda m: set_at(m, ("skeleton", "fps"), 0)),
        "streaming.window 0": manifest_edit(lambda m: m.get("streaming") and set_at(m, ("streaming", "window"), 0)),
        "sampling_defaults.top_p 7": manifest_edit(lambda m: set_at(m, ("sampling_defaults", "top_p"), 7)),
        "text_encoder.max_length 0": manifest_edit(lambda m: set_at(m, ("text_encoder", "max_length"), 0)),
        "files: ../ name": rename_listed(graphs[0], "../" + graphs[0]),
        "files: absolute name": rename_listed(graphs[0], "/etc/passwd"),
        "files: sub/folder name": rename_listed(graphs[0], "sub/" + graphs[0]),
        "files: tokenizer outside": rename_listed("tokenizer.json", "../tokenizer.json"),
        "tokenizer: garbage (hash forged)": file_bytes("tokenizer.json", lambda b: b"{not a tokenizer", forge=True),
        "tokenizer: empty json (hash forged)": file_bytes("tokenizer.json", lambda b: b"{}", forge=True),
        "tokenizer: a symlink outside": replace_path("tokenizer.json", outside_symlink),
        "tokenizer: a folder": replace_path("tokenizer.json", lambda f, p: p.mkdir()),
        "tokenizer: missing": replace_path("tokenizer.json", lambda f, p: None),
        "tokenizer: a normalizer that expands 200,000-fold (hash forged)": tokenizer_part(
            "normalizer", {"type": "Replace", "pattern": {"String": "a"}, "content": "a" * 200_000}),
        "tokenizer: a Prepend inside a Sequence (hash forged)": tokenizer_part(
            "normalizer", {"type": "Sequence", "normalizers": [{"type": "Prepend", "prepend": "x" * 100_000}]}),
        "tokenizer: an unknown model (hash forged)": tokenizer_part("model", {"type": "Unigram", "vocab": []}),
        "manifest: a link to another manifest": manifest_link(None),
        "manifest: a link to /dev/zero": manifest_link(lambda f: Path("/dev/zero")),
        "manifest: a link to a pipe": manifest_link(lambda f: (os.mkfifo(f.parent / "pipe"), f.parent / "pipe")[1]),
        "files: a 300-byte name": manifest_edit(lambda m: m["files"].update({"x" * 296 + ".onnx": m["files"][graphs[0]]})),
        "step.onnx: a cache twice as long as fed (hash forged)": graph_edit("step.onnx", doubled_presents),
        "decoder.onnx: fails only when run (hash forged)": graph_edit("decoder.onnx", failing_reshape),
        "lookup.onnx: fails only when run (hash forged)": graph_edit("lookup.onnx", failing_reshape),
    }
    for g in graphs:
        cases.update({
            f"{g}: truncated": file_bytes(g, lambda b: b[: len(b) // 2], forge=False),
            f"{g}: truncated (hash forged)": file_bytes(g, lambda b: b[: len(b) // 2], forge=True),
            f"{g}: one byte flipped": file_bytes(g, lambda b: b[:100] + bytes([b[100] ^ 1]) + b[101:], forge=False),
            f"{g}: garbage (hash forged)": file_bytes(g, lambda b: os.urandom(len(b)), forge=True),
            f"{g}: empty (hash forged)": file_bytes(g, lambda b: b"", forge=True),
            f"{g}: a symlink outside": replace_path(g, outside_symlink),
            f"{g}: a symlink inside": replace_path(g, lambda f, p: p.symlink_to(f / "tokenizer.json")),
            f"{g}: a folder": replace_path(g, lambda f, p: p.mkdir()),
            f"{g}: missing": replace_path(g, lambda f, p: None),
            f"{g}: NaN weights (hash forged)": nan_weights(g),
            f"{g}: external data inside": external_data(g, outside=False),
            f"{g}: external data outside": external_data(g, outside=True),
        })
    for a, b in zip(graphs, graphs[1:]):
        cases[f"swapped {a} and {b} (hashes forged)"] = swap_files(a, b)
    cases["step: 2 GB sparse file"] = sparse_graph("step.onnx", 2 << 30)
    for path, value in list(leaves(m)):
        if not path or path[0] == "files" and len(path) > 2:
            continue
        name = ".".join(map(str, path))
        if len(path) <= 3:
            cases[f"{name}: deleted"] = manifest_edit(lambda m, p=path: delete_at(m, p))
        for label, wrong in (("null", None), ("a string", "x"), ("a list", [1]), ("negative", -1), ("true", True)):
            if wrong != value and type(wrong) is not type(value) and len(path) <= 3:
                cases[f"{name}: {label}"] = manifest_edit(lambda m, p=path, w=wrong: set_at(m, p, w))
    return cases


def random_case(m: dict, rng: np.random.Generator, graphs: list[str]) -> tuple[str, Case]:
    """One seeded random mutation (make fuzz): a manifest leaf replaced, deleted or scaled, or bytes of a file
    flipped, cut or repeated (hash forged or not)."""
    kind = rng.integers(4)
    if kind <= 1:
        paths = [p for p, _ in leaves(m) if p]
        path = paths[rng.integers(len(paths))]
        pool = [None, True, False, 0, -1, 1, 2 ** 31, 2 ** 63, -(2 ** 63), 1e308, -1e-308, 0.5, "", "x", "../x",
                "/etc/passwd", [], {}, [0] * 3, {"a": 1}, float("nan"), float("inf")]
        if kind == 0:
            wrong = pool[rng.integers(len(pool))]
            return f"set {'.'.join(map(str, path))} = {wrong!r}", manifest_edit(lambda mm: set_at(mm, path, wrong))
        return f"delete {'.'.join(map(str, path))}", manifest_edit(lambda mm: delete_at(mm, path))
    name = graphs[rng.integers(len(graphs))] if kind == 2 else "tokenizer.json"
    forge = bool(rng.integers(2))
    at, n = int(rng.integers(1 << 20)), int(rng.integers(1, 64))
    how = int(rng.integers(3))

    def transform(b: bytes) -> bytes:
        i = at % max(len(b), 1)
        if how == 0:
            return b[:i] + bytes(x ^ 0xFF for x in b[i:i + n]) + b[i + n:]
        if how == 1:
            return b[:i]
        return b[:i] + b[i:i + n] * 1000 + b[i + n:]
    return f"{name}: {['flip', 'cut', 'repeat'][how]} at {at} ({'hash forged' if forge else 'hash kept'})", \
        file_bytes(name, transform, forge)


# ----------------------------------------------------------------------------------------------- running

class _OutsideReads:
    """Records every file opened outside the allowed folders (a Python audit hook: open() and os.open)."""

    def __init__(self):
        self.allowed: list[str] = []
        self.seen: list[str] = []
        sys.addaudithook(self._hook)

    def _hook(self, event, args):
        if event == "open" and self.allowed and isinstance(args[0], (str, bytes, os.PathLike)):
            if os.fsdecode(args[0]) == ".":     # files.py's O_TMPFILE open, relative to a folder fd the hook cannot see
                return
            path = os.fsdecode(args[0])
            if len(args) > 2 and isinstance(args[2], int) and args[2] & getattr(os, "O_NOFOLLOW", 0):
                # opened without following a link: what is read is the entry itself, wherever a link points
                path = os.path.join(os.path.realpath(os.path.dirname(path)), os.path.basename(path))
            else:
                path = os.path.realpath(path)
            if not any(path == a or path.startswith(a + os.sep) for a in self.allowed):
                self.seen.append(path)


_AUDIT: _OutsideReads | None = None


def outcome(folder: Path, allowed: list[Path]) -> tuple[str, str]:
    """Load the bundle at `folder`, generate 1 s from each of its variants; -> (outcome, detail). `allowed`: folders whose files
    may be read (the bundle, Python's own, the installed packages)."""
    global _AUDIT
    if _AUDIT is None:
        _AUDIT = _OutsideReads()
    _AUDIT.allowed = [os.path.realpath(a) for a in allowed]
    _AUDIT.seen = []
    try:
        result = ("ok", "")
        for variant in Bundle.load(folder).variants:
            motion = MotionGenerator(folder, variant=variant).generate("a person walks forward", seconds=1, seed=0)
            if not np.isfinite(motion.joints).all():
                result = ("nonfinite", f"NaN or inf joints returned ({variant})")
    except (BundleError, ValueError) as e:
        text = str(e)
        named = folder.name in text or "manifest" in text or "field" in text
        result = ("refused", text) if named else ("crash", f"{type(e).__name__} naming nothing: {text}")
    except RecursionError as e:
        result = ("crash", f"RecursionError: {e}")
    except Exception as e:   # noqa: BLE001 - the point is to catch what should not happen
        result = ("crash", f"{type(e).__name__}: {e}")
    finally:
        _AUDIT.allowed = []
    if _AUDIT.seen:
        return "outside", f"opened {_AUDIT.seen[0]} ({result[0]}: {result[1][:200]})"
    return result


def allowed_folders(bundle_copy: Path) -> list[Path]:
    """Where a run may read: the bundle copy, Python and its packages, /proc and /sys (onnxruntime reads CPU
    facts there), /dev."""
    import numpy
    import onnxruntime

    import mogo_runtime
    roots = {bundle_copy, Path(sys.prefix), Path(sys.base_prefix), Path(numpy.__file__).parents[1],
             Path(onnxruntime.__file__).parents[1], Path(mogo_runtime.__file__).parent,   # imports on first use
             Path("/proc"), Path("/sys"), Path("/dev"), Path("/etc/localtime")}
    return sorted(roots)


def run_case(good: Path, work: Path, case: Case, time_limit_s: float = 20.0) -> tuple[str, str, float]:
    """Apply `case` to a fresh copy of `good` under `work`; -> (outcome, detail, seconds)."""
    folder = work / "bundle"
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    shutil.copytree(good, folder)
    case(folder)
    start = time.perf_counter()
    result, detail = outcome(folder, allowed_folders(folder))
    took = time.perf_counter() - start
    if took > time_limit_s:
        return "hang", f"took {took:.1f} s ({result}: {detail[:200]})", took
    return result, detail, took
