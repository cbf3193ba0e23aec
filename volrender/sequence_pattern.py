"""File-name patterns of frame sequences and --frames (sequence.py renders them).

Patterns: `####` or `@@@@` (any number: zero-padded to that width), `$F4` (Houdini),
`%04d` / `%d` (printf), or a glob (`smoke_*.vdb`: the frame number is the last run of
digits in each name); fileseq reads the padding. `--frames A-B[:STEP]` (also `A-BxSTEP`
and `A-BySTEP` as VFX tools write them, `N`, and comma-separated lists; fileseq expands
them) picks frames; missing input frames are named before anything renders. A fuzz
target (fuzz/targets.py) reads patterns and --frames.
"""
from __future__ import annotations

import fnmatch
import glob as globmod
import re
from dataclasses import dataclass
from pathlib import Path

from .errors import UserError

_HASHES = re.compile(r"#+")
_PRINTF = re.compile(r"%(0?)(\d*)d")
# padding as VFX tools write it (fileseq reads its width): @@@@ (one digit each, as
# Houdini and Nuke), $F4 (Houdini); names an existing file does not count as a pattern
_VFX = re.compile(r"@+|\$F\d*")
_TOKEN = re.compile(r"#+|%0?\d*d|@+|\$F\d*")
_GLOB = re.compile(r"[*?\[]")
MAX_WIDTH = 32                  # digits a frame number is padded to, at most

@dataclass(frozen=True)
class Pattern:
    """A frame-numbered path: `prefix` + frame (zero-padded to `width`) + `suffix`, or a glob."""
    text: str
    prefix: str = ""
    suffix: str = ""
    width: int = 0
    glob: bool = False

    def path(self, frame: int) -> Path:
        if self.glob:
            raise ValueError("a glob names no single frame")
        return Path(f"{self.prefix}{frame:0{self.width}d}{self.suffix}")

    def matches(self) -> dict[int, Path]:
        """{frame: path} of the files a glob matches; a file's frame is the last run of
        digits in what the wildcards matched (files without one are not frames)."""
        rx = re.compile(_glob_regex(Path(self.text).name))
        out = {}
        for name in sorted(globmod.glob(self.text)):
            m = rx.fullmatch(Path(name).name)
            digits = re.findall(r"\d+", "".join(g or "" for g in m.groups())) if m else []
            if digits:
                out.setdefault(int(digits[-1]), Path(name))
        return out


def _glob_regex(pattern: str) -> str:
    """A regex for a glob with one capturing group per wildcard (*, ?, [...])."""
    out, i = [], 0
    while i < len(pattern):
        c = pattern[i]
        if c == "*":
            out.append("(.*)")
        elif c == "?":
            out.append("(.)")
        elif c == "[":
            start = i + 1 + (pattern[i + 1:i + 2] == "!")
            j = pattern.find("]", start + 1)
            if j < 0:
                out.append(re.escape(c))
            else:
                # fnmatch's own translation of the set: it escapes what a regex set would
                # read otherwise and drops reversed ranges ('[v-9]'), as glob does
                out.append("(" + fnmatch.translate(pattern[i:j + 1])[4:-3] + ")")
                i = j
        else:
            out.append(re.escape(c))
        i += 1
    return "".join(out)


def is_pattern(text: str) -> bool:
    if _VFX.search(text) and not _is_file(text):
        return True
    return bool(_HASHES.search(text) or _PRINTF.search(text) or _GLOB.search(Path(text).name))


def _is_file(text) -> bool:
    try:
        return Path(text).is_file()
    except (OSError, ValueError):
        return False


def _padding(token: str) -> int:
    """The digits a frame token pads to, as fileseq reads it (one per # or @, $F4: 4,
    %04d: 4); widths of more than 4 digits are refused before they are read."""
    import fileseq
    digits = re.sub(r"\D", "", token)
    if len(digits) > 4:
        return MAX_WIDTH + 1
    if token.startswith("%") and not digits:
        return 0                       # %d: no padding
    return fileseq.getPaddingNum(token, pad_style=fileseq.PAD_STYLE_HASH1)


def parse_pattern(text: str, *, output=False) -> Pattern:
    """A Pattern from `####`, `%04d`, `@@@@`, `$F4` (fileseq reads the padding) or (inputs
    only) a glob; one frame token only (a file's own name with @ in it is no pattern)."""
    text = str(text)
    rx = _TOKEN if not (_VFX.search(text) and _is_file(text)) else re.compile(r"#+|%0?\d*d")
    tokens = [m.group(0) for m in rx.finditer(text)]
    if len(tokens) > 1:
        raise UserError(f"the pattern {text!r} has {len(tokens)} frame numbers",
                        fix="use one #### (or one %04d, @@@@, $F4) per pattern")
    if tokens:
        m = rx.search(text)
        width = _padding(m.group(0))
        if width > MAX_WIDTH:
            raise UserError(f"the pattern {_short(text)!r} pads frame numbers to {width} digits, "
                            f"more than {MAX_WIDTH}", fix="use fewer # (or a smaller %0Nd)")
        return Pattern(text, text[:m.start()], text[m.end():], width)
    if _GLOB.search(Path(text).name):
        if output:
            raise UserError(f"the output {text!r} is a glob", fix="name output frames with #### or %04d")
        return Pattern(text, glob=True)
    raise UserError(f"{text!r} has no frame number",
                    fix="mark it with #### (any number of #), %04d, or a quoted glob")


MAX_FRAMES = 1_000_000          # frames one --frames may name, all its parts together


def parse_frames(text: str) -> list[int]:
    """`A-B[:STEP]` (also `A-BxSTEP` as VFX tools write it, and `A-BySTEP`: the frames
    that step skips), `N`, or comma-separated lists of those -> sorted frame numbers (at
    most MAX_FRAMES, each of at most 18 digits). Each part is checked here, then expanded
    by fileseq.FrameSet (volrender's `:` is fileseq's `x`)."""
    import fileseq
    frames, count = [], 0
    for part in str(text).split(","):
        m = re.fullmatch(r"\s*(-?[0-9]+)\s*(?:-\s*(-?[0-9]+)\s*(?:([:xy])\s*([0-9]+)\s*)?)?",
                         part)
        if not m:
            raise UserError(f"--frames: cannot read {_short(part.strip())!r}",
                            fix="give A-B[xSTEP], N, or a comma-separated list, e.g. 1-240x2")
        if max(len(g.lstrip("-")) for g in m.groups() if g is not None) > 18:
            raise UserError(f"--frames: {_short(part.strip())!r} has a number of more than 18 "
                            "digits", fix="give frame numbers below 10^18")
        a = int(m.group(1))
        b = int(m.group(2)) if m.group(2) is not None else a
        kind, step = m.group(3) or "x", int(m.group(4) or 1)
        if b < a or step < 1:
            raise UserError(f"--frames: {_short(part.strip())!r} is empty",
                            fix="give A-B with A <= B and STEP >= 1")
        count += (b - a) // step + 1 if kind != "y" else b - a + 1
        if count > MAX_FRAMES:
            raise UserError(f"--frames {_short(str(text).strip())!r} names more than a million "
                            "frames", fix="render at most a million frames per run")
        spec = f"{a}-{b}{'y' if kind == 'y' else 'x'}{step}" if m.group(2) is not None else str(a)
        frames.extend(int(f) for f in fileseq.FrameSet(spec))
    return sorted(set(frames))


def _short(text: str) -> str:
    return text if len(text) <= 80 else text[:40] + "..." + text[-30:]


def frame_number(path) -> int | None:
    """The frame number of a file: the last run of digits in its name's stem."""
    digits = re.findall(r"\d+", Path(path).stem)
    return int(digits[-1]) if digits else None


def explicit_inputs(paths, frames=None) -> dict[int, Path]:
    """{frame: path} of several input files (an unquoted glob the shell expanded), each
    numbered by the last run of digits in its name."""
    out = {}
    for p in paths:
        f = frame_number(p)
        if f is None:
            raise UserError("an input of the sequence has no frame number in its name",
                            path=p, fix="name the frames with their numbers (smoke_0001.vdb)")
        if f in out:
            raise UserError(f"frame {f} is given twice: {out[f]} and {p}", path=p,
                            fix="give each frame once")
        out[f] = Path(p)
    if frames is not None:
        missing = [f for f in frames if f not in out]
        if missing:
            raise UserError(f"--frames asks for frames the inputs do not have: "
                            f"{', '.join(map(str, missing[:8]))}", fix="give those files too")
        out = {f: out[f] for f in frames}
    return dict(sorted(out.items()))


def _on_disk(pattern: Pattern) -> dict[int, Path]:
    """{frame: path} of the files a #### / %04d pattern names that exist (any number of
    digits where the width is 0, at least the width's otherwise)."""
    folder = Path(pattern.prefix).parent
    head, tail = Path(pattern.prefix).name, pattern.suffix
    rx = re.compile(re.escape(head) + r"(\d{%d,})" % max(pattern.width, 1) + re.escape(tail))
    found = {}
    try:
        names = sorted(p.name for p in folder.iterdir()) if folder.is_dir() else []
    except OSError:
        names = []
    for name in names:
        m = rx.fullmatch(name)
        if m and (pattern.width == 0 or len(m.group(1)) == pattern.width or
                  m.group(1)[0] != "0"):
            found.setdefault(int(m.group(1)), folder / name)
    return found


def frame_inputs(pattern: Pattern, frames=None) -> dict[int, Path]:
    """{frame: input path} for the frames asked for (every one must exist); without
    --frames, the frames found on disk."""
    if pattern.glob:
        found = pattern.matches()
        if not found:
            raise UserError(f"no file matches {pattern.text!r}", fix="check the pattern (quote it)")
        wanted = frames if frames is not None else sorted(found)
        missing = [f for f in wanted if f not in found]
        paths = {f: found[f] for f in wanted if f in found}
    else:
        if frames is None:
            found = _on_disk(pattern)
            if not found:
                raise UserError(f"no file matches {pattern.text!r}",
                                fix="check the pattern, or give --frames A-B")
            return found
        paths = {f: pattern.path(f) for f in frames}
        missing = [f for f, p in paths.items() if not p.is_file()]
    if missing:
        shown = ", ".join(f"{f} ({paths.get(f, pattern.text)})" if not pattern.glob else str(f)
                          for f in missing[:8])
        more = f" and {len(missing) - 8} more" if len(missing) > 8 else ""
        raise UserError(f"{len(missing)} of {len(frames or paths)} frames are missing: {shown}{more}",
                        path=pattern.text, fix="provide them, or pick the frames that exist with --frames")
    return paths
