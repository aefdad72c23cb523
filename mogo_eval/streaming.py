"""Endless, steerable streams: does a character follow a new prompt every few seconds, for minutes, smoothly and
in bounded memory and time?

    mogo-eval stream --bundle bundles/base --variant int8 --minutes 10 --json outputs/stream_eval.json

One stream (`MotionGenerator.stream`) gets a new prompt every 4-10 s (seeded): a random action family, never the
same twice in a row, in a random phrasing from that family's held-out (test + val) captions. Then:

1. follows prompts: each segment without its first second is one clip for the project's action classifier
   (quality.py; it pools over any length, trained on 2-10 s crops, so no fixed windows are needed); accuracy
   overall, per family, first vs last minute.
2. reacts: per switch, the start of the first 2 s window (sliding by one token, 0.2 s, from the switch on, within
   the segment) the classifier labels as the new family, minus the switch time; a segment where no window does
   counts as its whole length.
3. smooth transitions (FlowMDM's measures): jerk = third finite difference of joint positions times fps^3; per
   frame the largest joint's jerk magnitude; in +-1 s around each switch its peak and its area (sum / fps), means
   over switches, against the same around the segment boundaries of the data's own long sequences. Foot skating
   and the largest per-frame root step, stream vs data.
4. does not drift: root height, bone lengths, accuracy, first minute vs last minute.
5. bounded: resident memory (current and peak) after the first minute vs at the end, time per token.

The judge is calibrated on the data's own long sequences (test + val): measures 1 and 2 with their timed segments
(`judge_on_data`), what a motion that follows its timeline exactly scores.

"First/last minute" are the first and last min(60 s, half the stream). The stream runs first, before the
classifier judges anything, so the memory and time it reports are the stream's own.
"""
from __future__ import annotations

import math
import resource
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
from tqdm import tqdm

from mogo_export.data.dataset import load_mean_std, normalize
from mogo_runtime.kinematics.features import recover_from_ric

REACT_WINDOW_S = 2.0         # the classifier's shortest training crop (40 frames at 20 fps)
SETTLE_S = 1.0               # each segment is judged without its first second
TRANSITION_HALF_S = 1.0      # +-1 s around a switch or a data segment boundary (FlowMDM)
CONTACT_HEIGHT = 0.05        # m: a toe below this is on the ground
SKATE_STEP = 0.025           # m per frame: a grounded toe moving more than this horizontally skates
INTERVAL_S = (4.0, 10.0)     # seconds between prompts


# ----------------------------------------------------------------------------------------------- measures

def jerk_per_frame(joints: np.ndarray, fps: float) -> np.ndarray:
    """(T, J, 3) positions -> (T - 3,) the largest joint's jerk magnitude (m/s^3) per frame (third finite
    difference of frames t..t+3)."""
    jerk = np.diff(joints.astype(np.float64), n=3, axis=0) * fps ** 3                  # (T - 3, J, 3)
    return np.linalg.norm(jerk, axis=-1).max(-1)


def skating_frames(joints: np.ndarray, toes: tuple[int, int]) -> np.ndarray:
    """(T, J, 3) -> (T - 1,) bool: frame t -> t+1 has a toe below CONTACT_HEIGHT at both frames that moves more
    than SKATE_STEP horizontally (x, z)."""
    feet = joints[:, list(toes)]                                                        # (T, 2, 3)
    contact = (feet[:-1, :, 1] < CONTACT_HEIGHT) & (feet[1:, :, 1] < CONTACT_HEIGHT)    # (T - 1, 2)
    step = np.linalg.norm(feet[1:][..., [0, 2]] - feet[:-1][..., [0, 2]], axis=-1)      # (T - 1, 2)
    return (contact & (step > SKATE_STEP)).any(-1)


def root_steps(joints: np.ndarray) -> np.ndarray:
    """(T, J, 3) -> (T - 1,) root displacement per frame, metres."""
    return np.linalg.norm(np.diff(joints[:, 0].astype(np.float64), axis=0), axis=-1)


def transition_measures(motions: list[tuple[np.ndarray, list[int]]], fps: float, toes: tuple[int, int]) -> dict:
    """Jerk, skating and root steps in +-TRANSITION_HALF_S around each boundary frame of each (joints, boundaries),
    and skating and root steps over the whole motions. Boundaries too close to an end are skipped."""
    half = round(TRANSITION_HALF_S * fps)
    peak, area, skate, steps = [], [], [], []
    all_skate, all_steps, all_jerk = [], [], []
    for joints, boundaries in motions:
        jerk = jerk_per_frame(joints, fps)
        all_skate.append(skating_frames(joints, toes))
        all_steps.append(root_steps(joints))
        all_jerk.append(jerk)
        for b in boundaries:
            if b - half < 0 or b + half > len(joints):
                continue
            window = jerk[b - half:b + half - 3]        # the frames whose 4-frame difference lies in the window
            peak.append(window.max())
            area.append(window.sum() / fps)
            skate.append(skating_frames(joints[b - half:b + half], toes))
            steps.append(root_steps(joints[b - half:b + half]).max())
    if not peak:
        raise ValueError(f"no boundary has {TRANSITION_HALF_S:g} s of motion on both sides")
    return {"transitions": len(peak), "peak_jerk": float(np.mean(peak)), "area_under_jerk": float(np.mean(area)),
            "skating_ratio_transitions": float(np.concatenate(skate).mean()),
            "root_step_max_transitions": float(np.max(steps)),
            "skating_ratio": float(np.concatenate(all_skate).mean()),
            "root_step_max": float(np.concatenate(all_steps).max()),
            "mean_jerk": float(np.concatenate(all_jerk).mean())}


def bone_lengths(joints: np.ndarray, parents) -> np.ndarray:
    """(T, J, 3) -> (T, bones) length of every joint-parent bone."""
    child = [j for j, p in enumerate(parents) if p >= 0]
    return np.linalg.norm(joints[:, child] - joints[:, [parents[j] for j in child]], axis=-1)


def memory_mb() -> tuple[float, float]:
    """(current, peak) resident set size of this process, MB (VmRSS, VmHWM; getrusage's peak elsewhere)."""
    try:
        fields = dict(line.split(":", 1) for line in Path("/proc/self/status").read_text().splitlines()
                      if line.startswith(("VmRSS", "VmHWM")))
        return float(fields["VmRSS"].split()[0]) / 1024, float(fields["VmHWM"].split()[0]) / 1024
    except (OSError, KeyError, ValueError):
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        return peak, peak


# ------------------------------------------------------------------------------------------- the stream

@dataclass
class Prompt:
    token: int          # planned start (tokens)
    family: str
    text: str


def plan_prompts(captions: dict[str, list[str]], total_tokens: int, per_token: float,
                 rng: np.random.Generator) -> tuple[list[Prompt], int]:
    """A prompt every INTERVAL_S (uniform, whole tokens): a random family, never the previous one, in a random
    caption of it. -> (prompts, end token): the stream ends where the segment that reaches total_tokens ends."""
    families = sorted(f for f, texts in captions.items() if texts)
    if len(families) < 2:
        raise ValueError(f"a stream that switches actions needs held-out captions of 2 families or more, got "
                         f"{families}")
    lo, hi = (round(s / per_token) for s in INTERVAL_S)
    prompts, token, prev = [], 0, None
    while token < total_tokens:
        family = str(rng.choice([f for f in families if f != prev]))
        prompts.append(Prompt(token, family, str(rng.choice(captions[family]))))
        token += int(rng.integers(lo, hi + 1))
        prev = family
    return prompts, token


@dataclass
class StreamRun:
    """What the stream loop recorded; all arrays were allocated (and touched) before the first frame."""
    features: np.ndarray        # (T, D)
    joints: np.ndarray          # (T, J, 3)
    switch_tokens: list[int]    # the token each prompt took effect at (0 for the first)
    burst_tokens: np.ndarray    # tokens sampled when each burst of frames began
    burst_time: np.ndarray      # perf_counter seconds at each burst's first frame
    memory: list[dict]          # {"seconds", "rss_mb", "peak_rss_mb"} at each mark
    first_frame_s: float
    wall_s: float


def run_stream(gen, prompts: list[Prompt], end_token: int, seed: int, marks: list[float],
               progress: bool = True) -> StreamRun:
    """Stream to end_token, switching to prompt i at the first token the loop can act at on or after its plan
    (tokens come `chunk` at a time, so up to chunk - 1 tokens late; the actual tokens are recorded). Memory is
    read when the stream reaches each of `marks` (seconds of motion)."""
    ds, fps = gen.dims.downsample, gen.dims.fps
    frames = end_token * ds
    features = np.full((frames, gen.dims.feature_dim), np.nan, np.float32)
    joints = np.full((frames, gen.skeleton.num_joints, 3), np.nan, np.float32)
    burst_tokens = np.full(end_token + 1, -1, np.int64)
    burst_time = np.full(end_token + 1, np.nan)
    mark_frames = sorted({min(frames, round(m * fps)) for m in marks})
    memory, bursts, pending = [], 0, 1
    bar = tqdm(total=frames, desc="stream", unit="frame", disable=not progress)
    t0 = time.perf_counter()
    stream = gen.stream(prompts[0].text, seed=seed)
    seen = -1
    try:
        for frame in stream:
            i, tokens = frame.index, stream.tokens
            if tokens != seen:                        # a new burst: the loop sampled and decoded since the last
                burst_tokens[bursts], burst_time[bursts] = tokens, time.perf_counter()
                bursts, seen = bursts + 1, tokens
                bar.update(i - bar.n)
            features[i], joints[i] = frame.features, frame.joints
            if mark_frames and i + 1 == mark_frames[0]:
                rss, peak = memory_mb()
                memory.append({"seconds": (i + 1) / fps, "rss_mb": rss, "peak_rss_mb": peak})
                mark_frames.pop(0)
            if i + 1 == frames:
                break
            # all decoded frames are out: the next token sampled is token `tokens`
            if pending < len(prompts) and i + 1 == tokens * ds and tokens >= prompts[pending].token:
                stream.set_prompt(prompts[pending].text)
                pending += 1
    finally:
        stream.close()
    bar.update(frames - bar.n)
    bar.close()
    return StreamRun(features, joints, [0] + [t for t, _, _ in stream.switches], burst_tokens[:bursts],
                     burst_time[:bursts], memory, float(burst_time[0] - t0), time.perf_counter() - t0)


# ----------------------------------------------------------------------------------------------- judging

def _classify_all(model, families, clips: list[np.ndarray], batch: int = 256) -> list[str]:
    from .quality import classify

    out: list[str] = []
    for i in range(0, len(clips), batch):
        out += classify(model, families, clips[i:i + batch])[0]
    return out


def reaction_times(model, families, feats_norm: np.ndarray, segments: list[tuple[int, int, str]], fps: float,
                   step: int) -> list[dict]:
    """Per segment (start frame, end frame, family): seconds from its start to the first REACT_WINDOW_S window
    (sliding by `step` frames, inside the segment) labelled as its family; never -> the segment's length."""
    width = round(REACT_WINDOW_S * fps)
    windows, owner = [], []
    for k, (a, b, _) in enumerate(segments):
        for s in range(a, b - width + 1, step):
            windows.append(feats_norm[s:s + width])
            owner.append((k, s))
    preds = _classify_all(model, families, windows)
    first: dict[int, int] = {}
    for (k, s), p in zip(owner, preds):
        if p == segments[k][2] and k not in first:
            first[k] = s
    return [{"seconds": ((first[k] if k in first else b) - a) / fps, "detected": k in first}
            for k, (a, b, _) in enumerate(segments)]


class Reference(NamedTuple):
    """One of the data's long sequences."""
    features: np.ndarray        # (T - 1, D) de-normalised
    joints: np.ndarray          # (T, J, 3)
    segments: list              # mogo_export.data.dataset.Segment (family, start, end) in order


def reference_motions(data: Path, num_joints: int, splits=("test", "val")) -> tuple[list[Reference], list[str]]:
    """The data's long sequences of `splits` (all splits if they hold none), and the splits used. Joints from
    new_joints/ when present, else recovered from the features."""
    from mogo_export.data.dataset import read_segments, read_split

    segments = read_segments(data)
    ids = [cid for split in splits for cid in read_split(data, split) if cid in segments]
    if not ids:
        ids, splits = sorted(segments), ("train", "val", "test")
    if not ids:
        raise ValueError(f"{data / 'dataset.json'} has no 'segments': the data has no long sequences to compare with")
    out = []
    for cid in ids:
        features = np.load(data / "new_joint_vecs" / f"{cid}.npy")
        path = data / "new_joints" / f"{cid}.npy"
        out.append(Reference(features, np.load(path) if path.is_file() else recover_from_ric(features, num_joints),
                             segments[cid]))
    return out, list(splits)


def judge_on_data(model, families, ref: list[Reference], mean: np.ndarray, std: np.ndarray, fps: float,
                  step: int) -> dict:
    """Measures 1 and 2 on the data's own long sequences, segments as dataset.json times them: what a motion
    that follows its timeline exactly scores with this judge (its segments are shorter: 2-10 s)."""
    settle = round(SETTLE_S * fps)
    clips, truth, reactions = [], [], []
    for r in ref:
        feats = normalize(r.features, mean, std)
        spans = [(s.start, min(s.end, len(feats)), s.family) for s in r.segments]
        clips += [feats[a + settle:b] for a, b, _ in spans]
        truth += [f for _, _, f in spans]
        reactions += reaction_times(model, families, feats, spans[1:], fps, step)
    hits = np.array(_classify_all(model, families, clips)) == np.array(truth)
    times = np.array([x["seconds"] for x in reactions])
    return {"segments": len(truth), "accuracy": float(hits.mean()), "switches": len(reactions),
            "reaction_median_s": float(np.median(times)), "reaction_p90_s": float(np.percentile(times, 90)),
            "never": int(sum(not x["detected"] for x in reactions))}


def _ratio(a: float, b: float) -> float:
    return a / b if b else math.inf


def _windows(total_s: float) -> tuple[float, float]:
    """The first and last 'minute': [0, span) and [total - span, total), span = min(60 s, total / 2)."""
    span = min(60.0, total_s / 2)
    return span, total_s - span


def held_out_captions(data: Path, families: list[str]) -> dict[str, list[str]]:
    """family -> every distinct caption of its held-out (test + val) single-action items."""
    from .quality import held_out_items

    captions: dict[str, list[str]] = {}
    for it, fam in held_out_items(data, families):
        have = captions.setdefault(fam, [])
        have += [c for c in it.captions if c not in have]
    return captions


def follows_and_reacts(model, families, feats_norm: np.ndarray, prompts: list[Prompt], starts: list[int],
                       fps: float, step: int, span: float, last_from: float) -> tuple[dict, dict, list[dict]]:
    """Measures 1 and 2 on the stream's normalised features; starts = each prompt's first frame."""
    ends = starts[1:] + [len(feats_norm)]
    settle = round(SETTLE_S * fps)
    judged = _classify_all(model, families, [feats_norm[a + settle:b] for a, b in zip(starts, ends)])
    segments = [{"start_s": a / fps, "end_s": b / fps, "family": p.family, "text": p.text, "predicted": pred,
                 "correct": pred == p.family} for p, a, b, pred in zip(prompts, starts, ends, judged)]

    def accuracy(rows) -> float:
        return float(np.mean([r["correct"] for r in rows])) if rows else math.nan

    def mid(r) -> float:
        return (r["start_s"] + r["end_s"]) / 2

    follows = {"accuracy": accuracy(segments), "segments": len(segments),
               "per_family": {f: accuracy([r for r in segments if r["family"] == f])
                              for f in sorted({r["family"] for r in segments})},
               "first_minute": accuracy([r for r in segments if mid(r) < span]),
               "last_minute": accuracy([r for r in segments if mid(r) >= last_from])}
    reactions = reaction_times(model, families, feats_norm,
                               [(a, b, p.family) for p, a, b in zip(prompts[1:], starts[1:], ends[1:])], fps, step)
    for r, seg in zip(reactions, segments[1:]):
        r.update(switch_s=seg["start_s"], family=seg["family"])
    times = np.array([r["seconds"] for r in reactions])
    reacts = {"switches": len(reactions), "median_s": float(np.median(times)), "p90_s": float(np.percentile(times, 90)),
              "never": int(sum(not r["detected"] for r in reactions)), "per_switch": reactions}
    return follows, reacts, segments


def transitions_vs_data(joints: np.ndarray, switch_frames: list[int], ref: list[Reference], skeleton,
                        fps: float) -> dict:
    """Measure 3: the stream around its switches vs the data's long sequences around their segment boundaries."""
    toes = (skeleton.foot_left[1], skeleton.foot_right[1])
    stream = transition_measures([(joints, switch_frames)], fps, toes)
    ref_t = transition_measures([(r.joints, [s.start for s in r.segments[1:]]) for r in ref], fps, toes)
    return {"stream": stream, "data": ref_t,
            "peak_jerk_ratio": _ratio(stream["peak_jerk"], ref_t["peak_jerk"]),
            "area_under_jerk_ratio": _ratio(stream["area_under_jerk"], ref_t["area_under_jerk"]),
            "mean_jerk_ratio": _ratio(stream["mean_jerk"], ref_t["mean_jerk"]),
            "skating_diff_pp": 100 * (stream["skating_ratio"] - ref_t["skating_ratio"]),
            "skating_diff_pp_transitions": 100 * (stream["skating_ratio_transitions"]
                                                  - ref_t["skating_ratio_transitions"]),
            "root_step_ratio": _ratio(stream["root_step_max"], ref_t["root_step_max"]),
            "root_step_ratio_transitions": _ratio(stream["root_step_max_transitions"],
                                                  ref_t["root_step_max_transitions"])}


def drift(joints: np.ndarray, ref: list[Reference], parents, fps: float, span: float, last_from: float,
          follows: dict) -> dict:
    """Measure 4: root height, bone lengths and accuracy, first vs last minute."""
    first, last = slice(0, round(span * fps)), slice(round(last_from * fps), len(joints))
    bones = bone_lengths(joints, parents)
    ref_bones = np.concatenate([bone_lengths(r.joints, parents) for r in ref]).mean(0)
    b_first, b_last = bones[first].mean(0), bones[last].mean(0)
    out = {"root_height_median_first_m": float(np.median(joints[first, 0, 1])),
           "root_height_median_last_m": float(np.median(joints[last, 0, 1])),
           "root_height_median_data_m": float(np.median(np.concatenate([r.joints[:, 0, 1] for r in ref]))),
           "bone_length_max_rel_change": float(np.max(np.abs(b_last - b_first) / b_first)),
           "bone_length_max_rel_vs_data_first": float(np.max(np.abs(b_first - ref_bones) / ref_bones)),
           "bone_length_max_rel_vs_data_last": float(np.max(np.abs(b_last - ref_bones) / ref_bones)),
           "accuracy_first_minute": follows["first_minute"], "accuracy_last_minute": follows["last_minute"]}
    out["root_height_change_m"] = out["root_height_median_last_m"] - out["root_height_median_first_m"]
    return out


def bounded(run: StreamRun, per_token: float, span: float, last_from: float, total_s: float) -> dict:
    """Measure 5: memory after the first minute vs at the end; wall time per token, first vs last minute."""
    at_span = next(m for m in run.memory if m["seconds"] >= span - 1e-9)
    end = run.memory[-1]
    dt, dtok = np.diff(run.burst_time), np.diff(run.burst_tokens)
    per_tok = dt / dtok                                    # each burst after the first: its wall time per token
    tok_s = run.burst_tokens[:-1] * per_token              # stream time its tokens start at
    in_first, in_last = tok_s < span, tok_s >= last_from
    out = {"rss_mb_first_minute": at_span["rss_mb"], "rss_mb_end": end["rss_mb"],
           "rss_growth_mb": end["rss_mb"] - at_span["rss_mb"],
           "peak_rss_mb_first_minute": at_span["peak_rss_mb"], "peak_rss_mb_end": end["peak_rss_mb"],
           "peak_rss_growth_mb": end["peak_rss_mb"] - at_span["peak_rss_mb"], "memory_marks": run.memory,
           "token_ms_first_minute": 1000 * float(dt[in_first].sum() / dtok[in_first].sum()),
           "token_ms_last_minute": 1000 * float(dt[in_last].sum() / dtok[in_last].sum()),
           "token_ms_mean": 1000 * float(dt.sum() / dtok.sum()),
           "token_ms_p99_burst": 1000 * float(np.percentile(per_tok, 99)),
           "first_frame_ms": 1000 * run.first_frame_s, "stream_wall_s": run.wall_s,
           "realtime_factor": total_s / run.wall_s}
    out["token_time_ratio"] = out["token_ms_last_minute"] / out["token_ms_first_minute"]
    return out


def stream_report(bundle: Path, data: Path, classifier: Path, variant: str = "int8", threads: int = 1,
                  seconds: float = 600.0, seed: int = 0, progress: bool = True) -> dict:
    """The whole measurement (module docstring); `classifier` is a classifier.pt of quality.train_classifier."""
    from mogo_runtime.generator import MotionGenerator

    from .quality import load_classifier

    if seconds < 2 * INTERVAL_S[1]:     # so the first and last 'minute' each hold a segment's midpoint
        raise ValueError(f"a stream to judge must be at least {2 * INTERVAL_S[1]:g} s long, got {seconds:g}")
    t_start = time.perf_counter()
    model, families = load_classifier(classifier)
    captions = held_out_captions(data, families)
    gen = MotionGenerator(bundle, variant=variant, threads=threads)
    if not gen.endless:
        raise ValueError(f"{bundle} was not trained for endless streams (its manifest has no 'streaming'), so its "
                         "streams cannot change prompt")
    fps, ds = gen.dims.fps, gen.dims.downsample
    prompts, end_token = plan_prompts(captions, max(1, round(seconds * fps / ds)), ds / fps,
                                      np.random.default_rng(seed))
    total_s = end_token * ds / fps
    span, last_from = _windows(total_s)
    run = run_stream(gen, prompts, end_token, seed, sorted({span, total_s, *np.arange(60.0, total_s, 60.0)}),
                     progress)

    mean, std = load_mean_std(data, gen.dims.feature_dim)
    starts = [t * ds for t in run.switch_tokens]
    follows, reacts, segments = follows_and_reacts(model, families, normalize(run.features, mean, std), prompts,
                                                   starts, fps, ds, span, last_from)
    ref, ref_splits = reference_motions(data, gen.skeleton.num_joints)
    report = {"bundle": str(bundle), "variant": variant, "threads": threads, "seed": seed, "data": str(data),
              "classifier": str(classifier), "streaming": asdict(gen.bundle.manifest.streaming),
              "stream_seconds": total_s, "requested_seconds": float(seconds), "minute_span_s": span,
              "data_splits": ref_splits, "data_sequences": len(ref), "definitions": DEFINITIONS,
              "follows": follows, "reacts": reacts,
              "judge_on_data": judge_on_data(model, families, ref, mean, std, fps, ds),
              "transitions": transitions_vs_data(run.joints, starts[1:], ref, gen.skeleton, fps),
              "drift": drift(run.joints, ref, gen.skeleton.parents, fps, span, last_from, follows),
              "bounded": bounded(run, ds / fps, span, last_from, total_s), "segments": segments}
    report["checks"] = checks(report)
    report["wall_seconds"] = time.perf_counter() - t_start
    return report


DEFINITIONS = {
    "segment_accuracy": "each segment without its first second is one clip for the classifier (it pools over any "
                        "length; trained on 2-10 s crops); correct when its label is the prompt's family",
    "reaction": "start of the first 2 s window (step 0.2 s, from the switch, inside the segment) labelled as the "
                "new family, minus the switch time; never -> the segment's length",
    "jerk": "third finite difference of joint positions * fps^3; per frame the largest joint's magnitude; peak = "
            "max and area = sum / fps over +-1 s around each switch / data boundary; means over them",
    "skating": "frames (t -> t+1) where a toe joint (skeleton foot_left/foot_right toe: 10, 11) is below 5 cm at "
               "both frames and moves more than 2.5 cm horizontally, over all frames (ankles 7, 8 are not used: "
               "they rest at 4.8-6 cm, on the 5 cm line)",
    "root_step": "max over frames of the root's displacement per frame (m)",
    "first_last_minute": "the first and last min(60 s, half the stream); a segment belongs to the one holding its "
                         "midpoint; a token timing to the one holding its token",
}


@dataclass
class Check:
    name: str
    value: float
    bar: str
    met: bool | None       # None: reported, no bar

    def row(self) -> dict:
        return {"name": self.name, "value": float(self.value), "bar": self.bar,
                "met": None if self.met is None else bool(self.met)}


def checks(r: dict) -> list[dict]:
    f, re, t, d, b = r["follows"], r["reacts"], r["transitions"], r["drift"], r["bounded"]
    bone_drift = d["bone_length_max_rel_vs_data_last"] - d["bone_length_max_rel_vs_data_first"]
    rows = [Check("segment accuracy", f["accuracy"], ">= 0.85", f["accuracy"] >= 0.85),
            Check("segment accuracy, first minute", f["first_minute"], ">= 0.85", f["first_minute"] >= 0.85),
            Check("segment accuracy, last minute", f["last_minute"], ">= 0.85", f["last_minute"] >= 0.85)]
    rows += [Check(f"  accuracy {fam}", acc, ">= 0.85", acc >= 0.85) for fam, acc in f["per_family"].items()]
    rows += [Check("reaction median (s)", re["median_s"], "<= 1.0", re["median_s"] <= 1.0),
             Check("reaction p90 (s)", re["p90_s"], "<= 2.0", re["p90_s"] <= 2.0),
             Check("switches never recognised", re["never"], "-", None),
             Check("  judge on the data's long sequences: accuracy", r["judge_on_data"]["accuracy"], "-", None),
             Check("  judge on the data: reaction median (s)", r["judge_on_data"]["reaction_median_s"], "-", None),
             Check("  judge on the data: reaction p90 (s)", r["judge_on_data"]["reaction_p90_s"], "-", None),
             Check("peak jerk ratio (stream/data)", t["peak_jerk_ratio"], "<= 1.5", t["peak_jerk_ratio"] <= 1.5),
             Check("area under jerk ratio", t["area_under_jerk_ratio"], "<= 1.5", t["area_under_jerk_ratio"] <= 1.5),
             Check("  peak jerk stream (m/s^3)", t["stream"]["peak_jerk"], "-", None),
             Check("  peak jerk data (m/s^3)", t["data"]["peak_jerk"], "-", None),
             Check("  area under jerk stream (m/s^2)", t["stream"]["area_under_jerk"], "-", None),
             Check("  area under jerk data (m/s^2)", t["data"]["area_under_jerk"], "-", None),
             Check("mean jerk ratio, whole motion", t["mean_jerk_ratio"], "-", None),
             Check("skating stream - data (pp)", t["skating_diff_pp"], "|x| <= 2", abs(t["skating_diff_pp"]) <= 2),
             Check("  skating stream / data (%)", 100 * t["stream"]["skating_ratio"], "-", None),
             Check("  skating data (%)", 100 * t["data"]["skating_ratio"], "-", None),
             Check("skating +-1 s of switches, stream - data (pp)", t["skating_diff_pp_transitions"], "|x| <= 2",
                   abs(t["skating_diff_pp_transitions"]) <= 2),
             Check("max root step ratio (stream/data)", t["root_step_ratio"], "<= 1.5", t["root_step_ratio"] <= 1.5),
             Check("max root step ratio, +-1 s of switches", t["root_step_ratio_transitions"], "<= 1.5",
                   t["root_step_ratio_transitions"] <= 1.5),
             Check("  max root step stream (m)", t["stream"]["root_step_max"], "-", None),
             Check("  max root step data (m)", t["data"]["root_step_max"], "-", None),
             Check("root height change, last - first minute (m)", d["root_height_change_m"], "|x| <= 0.05",
                   abs(d["root_height_change_m"]) <= 0.05),
             # bone lengths follow the action (a squat bends them unlike a walk), so "as good as the first minute"
             # compares each minute's deviation from the data's bones, not the minutes with each other
             Check("bone length deviation from data, last - first minute", bone_drift, "<= 0.01", bone_drift <= 0.01),
             Check("  bone length max deviation from data, first minute", d["bone_length_max_rel_vs_data_first"],
                   "-", None),
             Check("  bone length max deviation from data, last minute", d["bone_length_max_rel_vs_data_last"],
                   "-", None),
             Check("  bone length max change, last vs first minute", d["bone_length_max_rel_change"], "-", None),
             Check("accuracy last - first minute", d["accuracy_last_minute"] - d["accuracy_first_minute"],
                   ">= -0.10", d["accuracy_last_minute"] - d["accuracy_first_minute"] >= -0.10),
             Check("RSS growth, first minute -> end (MB)", b["rss_growth_mb"], "<= 5", b["rss_growth_mb"] <= 5),
             Check("peak RSS growth, first minute -> end (MB)", b["peak_rss_growth_mb"], "<= 5",
                   b["peak_rss_growth_mb"] <= 5),
             Check("  peak RSS first minute / end (MB)", b["peak_rss_mb_first_minute"], "-", None),
             Check("token time last / first minute", b["token_time_ratio"], "<= 1.1", b["token_time_ratio"] <= 1.1),
             Check("  ms per token first minute", b["token_ms_first_minute"], "-", None),
             Check("  ms per token last minute", b["token_ms_last_minute"], "-", None),
             Check("  ms per token p99 (per burst)", b["token_ms_p99_burst"], "-", None),
             Check("  time to first frame (ms)", b["first_frame_ms"], "-", None),
             Check("  real-time factor", b["realtime_factor"], "-", None)]
    return [c.row() for c in rows]


def print_report(report: dict) -> None:
    print(f"Endless stream on {report['bundle']} [{report['variant']}, {report['threads']} thread(s)]: "
          f"{report['stream_seconds']:.0f} s, {report['follows']['segments']} prompts, seed {report['seed']}; "
          f"'minute' = {report['minute_span_s']:g} s")
    print(f"{'measure':52s} {'value':>10s}  {'bar':10s} verdict")
    for c in report["checks"]:
        verdict = "-" if c["met"] is None else ("met" if c["met"] else "MISSED")
        print(f"{c['name']:52s} {c['value']:10.3f}  {c['bar']:10s} {verdict}")
    print(f"wall time {report['wall_seconds']:.1f} s (stream {report['bounded']['stream_wall_s']:.1f} s)")


def finite(report) -> bool:
    """Whether every number in the report is finite (what the JSON can carry as a number)."""
    if isinstance(report, dict):
        return all(finite(v) for v in report.values())
    if isinstance(report, list):
        return all(finite(v) for v in report)
    return not isinstance(report, float) or math.isfinite(report)
