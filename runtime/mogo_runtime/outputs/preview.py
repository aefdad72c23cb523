"""Stick-figure previews of joint motion: animated GIFs (Pillow), grids of several motions, MP4 (imageio-ffmpeg's ffmpeg).

The camera is fixed for a whole clip: a perspective 3/4 front view (the body faces +z in the rest pose,
y is up) aimed at the middle of everything the clip touches, zoomed so every frame fits. The floor is a
grid at the lowest joint height, with the root's path drawn on it. The person's left limbs are blue,
right limbs red, the spine and head dark grey. Frames are drawn straight into a small palette image,
so writing a GIF needs no colour quantisation and a 200-frame clip takes a fraction of a second.
"""
from __future__ import annotations

import math
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from ..checks import check_fps
from ..kinematics.skeleton import HUMANML3D, Skeleton, rest_positions
from .files import OutputError, staged_output, write_atomic

# Palette indices and colours.
BG, GRID, PATH, SHADOW, CENTRE, LEFT, RIGHT, TEXT, HEAD = range(9)
_PALETTE = [(246, 245, 240), (208, 207, 200), (150, 150, 145), (200, 199, 192), (70, 70, 70),
            (35, 105, 215), (215, 55, 45), (25, 25, 25), (250, 250, 250)]


@dataclass(frozen=True)
class Camera:
    azimuth_deg: float = 35.0     # around the vertical axis; 0 = straight in front of a body facing +z
    elevation_deg: float = 18.0   # above the horizon
    grid_step: float = 0.5        # metres between floor lines
    head_radius: float = 0.09     # metres


class PreviewError(OutputError, RuntimeError):
    """ffmpeg could not be run, or failed writing the video; the message names the file. An OutputError (an
    OSError) like every other failure to write an output, so `mogo` reports it in one line, and a RuntimeError
    as it always was."""


# ----------------------------------------------------------------------------------------------------
# public API

def render_frames(joints, skeleton: Skeleton = HUMANML3D, fps: float = 20.0, title: str | None = None,
                  size: tuple[int, int] = (320, 320), camera: Camera = Camera()) -> list[Image.Image]:
    """The preview of `joints` (T, J, 3) in metres as T palette ("P") images of `size` (width, height)."""
    pos = _check(joints, skeleton, fps, size)
    scene = _Scene(pos, skeleton, size, title, camera)
    scene.fit()
    return [scene.frame(t) for t in range(len(pos))]


def render_gif(path, joints, skeleton: Skeleton = HUMANML3D, fps: float = 20.0, title: str | None = None,
               size: tuple[int, int] = (320, 320), camera: Camera = Camera()) -> Path:
    """Write an animated GIF of `joints` (T, J, 3) metres at `fps` (atomically). Returns the path.
    GIF stores frame times in 1/100 s, so the frame time is 1000/fps ms rounded down to 10 ms."""
    return _save_gif(Path(path), render_frames(joints, skeleton, fps, title, size, camera), fps)


def render_grid_gif(path, motions, skeleton: Skeleton = HUMANML3D, fps: float = 20.0,
                    size: tuple[int, int] = (240, 240), columns: int | None = None,
                    camera: Camera = Camera()) -> Path:
    """Write one GIF showing several motions side by side: `motions` is a list of (title, joints (T, J, 3)).
    Each cell is `size`; all cells share one zoom so sizes compare; shorter clips hold their last frame."""
    motions = list(motions)
    if not motions:
        raise ValueError("render_grid_gif needs at least one (title, joints) pair, got none")
    scenes = []
    for n, item in enumerate(motions):
        if not (isinstance(item, (tuple, list)) and len(item) == 2):
            raise ValueError(f"motions[{n}] must be a (title, joints) pair, got {type(item).__name__}")
        title, joints = item
        scenes.append(_Scene(_check(joints, skeleton, fps, size, f"motions[{n}] joints"), skeleton, size,
                             str(title), camera))
    px_per_m = min(s.fit() for s in scenes)
    for s in scenes:
        s.fit(px_per_m)
    columns = columns or min(len(scenes), 4)
    if columns < 1:
        raise ValueError(f"columns must be >= 1, got {columns}")
    rows = math.ceil(len(scenes) / columns)
    W, H = size
    frames = []
    for t in range(max(len(s.pos) for s in scenes)):
        canvas = _new_image((W * columns, H * rows))
        for n, s in enumerate(scenes):
            canvas.paste(s.frame(min(t, len(s.pos) - 1)), ((n % columns) * W, (n // columns) * H))
        frames.append(canvas)
    return _save_gif(Path(path), frames, fps)


def render_mp4(path, joints, skeleton: Skeleton = HUMANML3D, fps: float = 20.0, title: str | None = None,
               size: tuple[int, int] = (320, 320), camera: Camera = Camera()) -> Path:
    """Write an H.264/MPEG-4 video by piping raw frames to ffmpeg (atomically): the binary the imageio-ffmpeg
    wheel ships (or the one IMAGEIO_FFMPEG_EXE names), so no system ffmpeg is needed."""
    import imageio_ffmpeg

    ffmpeg = imageio_ffmpeg.get_ffmpeg_exe()
    frames = render_frames(joints, skeleton, fps, title, size, camera)
    path = Path(path)
    W, H = size
    # ffmpeg writes the staged file itself (by a name that reaches our unnamed file), so a kill -9 of this process
    # leaves nothing in the folder either: ffmpeg, orphaned, finishes into a file that disappears with it
    with staged_output(path) as out, tempfile.TemporaryFile() as err:  # stderr to a file: ffmpeg never blocks on it
        cmd = [ffmpeg, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{W}x{H}",
               "-r", f"{fps:g}", "-i", "-", "-an", "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2",  # yuv420p: even sizes
               "-pix_fmt", "yuv420p", "-movflags", "+faststart", "-f", "mp4", out.external_name]
        try:
            proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stderr=err, pass_fds=out.pass_fds)
        except OSError as e:
            raise PreviewError(f"cannot run ffmpeg {ffmpeg!r} to write {path}: {e.strerror or e}") from None
        try:
            try:
                for f in frames:
                    proc.stdin.write(f.convert("RGB").tobytes())
                proc.stdin.close()
            except BrokenPipeError:
                pass  # ffmpeg died; its exit code and stderr say why
            code = proc.wait()
        except BaseException:
            proc.kill()      # interrupted: no ffmpeg left encoding a file nobody will keep
            proc.wait()
            raise
        if code != 0:
            err.seek(0)
            raise PreviewError(f"ffmpeg failed (exit {code}) writing {path}: "
                               f"{err.read().decode(errors='replace')[-2000:]}")
    return path


# ----------------------------------------------------------------------------------------------------
# drawing

class _Scene:
    """One clip seen by one fixed camera: projects joints, draws the static background once, then frames."""

    def __init__(self, pos: np.ndarray, skeleton: Skeleton, size, title, camera: Camera):
        self.pos, self.skeleton, self.size, self.title, self.cam = pos, skeleton, size, title, camera
        W, H = size
        self.line = max(2, round(min(W, H) / 110))
        self.font = _font(max(10, round(min(W, H) / 22)))
        self.small = _font(max(8, round(min(W, H) / 30)))
        self.title_lines = _wrap(title or "", self.font, W - 8, max_lines=2)
        self.top = 6 + len(self.title_lines) * (self.font.size + 3) if self.title_lines else 4
        rest = rest_positions(skeleton.offsets, skeleton.parents)
        # +1 for the body's left (rest-pose x > 0, the body facing +z), -1 for right, 0 on the midline
        self.side = [int(np.sign(x)) if abs(x) > 1e-6 else 0 for x in rest[:, 0]]
        # the highest leaf on the midline in the rest pose (HumanML3D's head, KIT's upper neck)
        leaves = [j for j in range(skeleton.num_joints) if j not in skeleton.parents and abs(rest[j, 0]) < 1e-6]
        self.head = max(leaves, key=lambda j: rest[j, 1]) if leaves else None
        self.bones = [(p, j) for j, p in enumerate(skeleton.parents) if p >= 0]

        self.floor = float(pos[..., 1].min())
        self.ground = pos[:, 0].copy()                  # the root's path on the floor
        self.ground[:, 1] = self.floor
        lo, hi = pos[..., [0, 2]].reshape(-1, 2).min(0), pos[..., [0, 2]].reshape(-1, 2).max(0)
        step = camera.grid_step
        self.grid_lo = np.floor((lo - 0.75) / step) * step
        self.grid_hi = np.ceil((hi + 0.75) / step) * step
        centre = np.array([(lo[0] + hi[0]) / 2, (self.floor + pos[..., 1].max()) / 2, (lo[1] + hi[1]) / 2])
        # Far enough back that the whole floor grid is in front of the camera.
        reach = float(np.linalg.norm([(self.grid_hi - self.grid_lo) / 2])) + abs(centre[1] - self.floor)
        dist = max(3.5, 1.6 * reach + 1.0)
        az, el = np.radians(camera.azimuth_deg), np.radians(camera.elevation_deg)
        eye = centre + dist * np.array([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])
        fwd = (centre - eye) / dist
        right = np.cross(fwd, [0.0, 1.0, 0.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        self.eye, self.basis, self.dist = eye, np.stack([right, up, fwd]), dist

    def _camera(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (..., 3) -> normalised image coordinates (..., 2) (y up) and depth (...)."""
        c = (p - self.eye) @ self.basis.T
        return c[..., :2] / c[..., 2:], c[..., 2]

    def fit(self, px_per_m: float | None = None) -> float:
        """Choose zoom and centring so every joint of every frame and the root path fit. Returns that zoom
        as pixels per metre at the scene's centre; pass `px_per_m` to impose one (shared in grids)."""
        W, H = self.size
        xy, _ = self._camera(np.concatenate([self.pos.reshape(-1, 3), self.ground]))
        lo, hi = xy.min(0), xy.max(0)
        margin = 0.06 * min(W, H)
        avail = np.array([W - 2 * margin, H - 2 * margin - self.top - self.small.size])
        fit = float(np.min(avail / np.maximum(hi - lo, 1e-6)))  # pixels per normalised image unit
        self.scale = fit if px_per_m is None else px_per_m * self.dist
        mid = (lo + hi) / 2
        self.offset = np.array([W / 2 - self.scale * mid[0],
                                self.top + (H - self.top - self.small.size) / 2 + self.scale * mid[1]])
        self.px, self.depth = self._project(self.pos)
        self.background = self._background()
        return fit / self.dist

    def _project(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xy, depth = self._camera(p)
        return np.stack([self.offset[0] + self.scale * xy[..., 0], self.offset[1] - self.scale * xy[..., 1]], -1), depth

    def _background(self) -> Image.Image:
        img = _new_image(self.size)
        draw = ImageDraw.Draw(img)
        (x0, z0), (x1, z1), y, step = self.grid_lo, self.grid_hi, self.floor, self.cam.grid_step
        for ends in ([[[x, y, z0], [x, y, z1]] for x in np.arange(x0, x1 + step / 2, step)]
                     + [[[x0, y, z], [x1, y, z]] for z in np.arange(z0, z1 + step / 2, step)]):
            (pa, pb), _ = self._project(np.array(ends, dtype=np.float64))
            draw.line([tuple(pa), tuple(pb)], fill=GRID, width=1)
        if len(self.ground) > 1:
            draw.line([tuple(q) for q in self._project(self.ground)[0]], fill=PATH, width=max(1, self.line // 2))
        for n, text in enumerate(self.title_lines):
            draw.text((4, 4 + n * (self.font.size + 3)), text, fill=TEXT, font=self.font)
        return img

    def frame(self, t: int) -> Image.Image:
        img = self.background.copy()
        draw = ImageDraw.Draw(img)
        px, depth = self.px[t], self.depth[t]
        # Shadow under the root, squashed by the view's elevation.
        (gx, gy), gd = self._project(self.ground[t])
        r = self.scale * 0.18 / gd
        rv = r * max(0.25, np.sin(np.radians(self.cam.elevation_deg)))
        draw.ellipse([gx - r, gy - rv, gx + r, gy + rv], fill=SHADOW)
        # Far bones first so near limbs are drawn over them.
        colour = {0: CENTRE, 1: LEFT, -1: RIGHT}
        for p, j in sorted(self.bones, key=lambda b: -(depth[b[0]] + depth[b[1]])):
            draw.line([tuple(px[p]), tuple(px[j])], fill=colour[self.side[j]], width=self.line)
        dot = self.line * 0.7
        for j in range(len(px)):
            draw.ellipse([px[j, 0] - dot, px[j, 1] - dot, px[j, 0] + dot, px[j, 1] + dot], fill=colour[self.side[j]])
        if self.head is not None:
            hr = self.scale * self.cam.head_radius / depth[self.head]
            hx, hy = px[self.head]
            draw.ellipse([hx - hr, hy - hr, hx + hr, hy + hr], fill=HEAD, outline=CENTRE, width=self.line)
        # A frame counter: also keeps every frame distinct, so GIF writers never merge frames.
        W, H = self.size
        draw.text((4, H - self.small.size - 4), f"{t + 1}/{len(self.pos)}", fill=TEXT, font=self.small)
        return img


def _font(size: int):
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: only the fixed bitmap font
        font = ImageFont.load_default()
        font.size = 11
        return font


def _wrap(text: str, font, width: int, max_lines: int) -> list[str]:
    """Greedy word wrap to `width` pixels; the last line ends in '...' if text is left over."""
    lines, words = [], text.split()
    while words and len(lines) < max_lines:
        line = words.pop(0)
        while words and font.getlength(line + " " + words[0]) <= width:
            line += " " + words.pop(0)
        lines.append(line)
    if words or (lines and font.getlength(lines[-1]) > width):
        last = lines[-1]
        while last and font.getlength(last + "...") > width:
            last = last[:-1]
        lines[-1] = last.rstrip() + "..."
    return lines


def _new_image(size) -> Image.Image:
    img = Image.new("P", tuple(size), BG)
    img.putpalette([c for rgb in _PALETTE for c in rgb])
    return img


# ----------------------------------------------------------------------------------------------------
# files and checks

def _save_gif(path: Path, frames: list[Image.Image], fps: float) -> Path:
    return write_atomic(path, lambda f: frames[0].save(f, format="GIF", save_all=True, append_images=frames[1:],
                                                        duration=round(1000.0 / fps), loop=0))


def _check(joints, skeleton: Skeleton, fps, size, what: str = "joints") -> np.ndarray:
    check_fps(fps)
    if not (isinstance(size, (tuple, list)) and len(size) == 2 and all(isinstance(s, int) and s >= 64 for s in size)):
        raise ValueError(f"size must be (width, height) in pixels, each an int >= 64, got {size!r}")
    return skeleton.check_joints(joints, what)
