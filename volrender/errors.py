"""User-facing errors: one line naming the file, the problem and the fix.

Messages name options as the caller spells them: `--density-scale` on the command line,
`density_scale=` from Python (`spelling`, set by the CLI for its run; `spell` rewrites the
flags a message was written with). `suggest` adds difflib's close matches ("did you mean").
"""
import contextvars
import difflib
import re
import sys


def printable(text) -> str:
    """`text` with every non-printable character escaped (\\x1b, \\n, \\udcff -> \\xff for
    undecodable bytes of a file name), so that nothing quoted from a file or a path can
    move the cursor, retitle or clear the terminal, or break the message's one line."""
    text = str(text)
    if text.isprintable():
        return text
    out = []
    for ch in text:
        if ch.isprintable():
            out.append(ch)
        elif "\udc80" <= ch <= "\udcff":             # a byte that was not UTF-8
            out.append(f"\\x{ord(ch) - 0xdc00:02x}")
        elif ch == "\n":
            out.append("\\n")
        elif ch == "\t":
            out.append("\\t")
        elif ord(ch) < 0x100:
            out.append(f"\\x{ord(ch):02x}")
        else:
            out.append(f"\\u{ord(ch):04x}")
    return "".join(out)


# "cli" while the command line runs (cli.main), else "python": how messages name options.
SPELLING = contextvars.ContextVar("volrender_spelling", default="python")
# Python keywords that have a flag (filled by scene.py from the settings knobs): only these
# flags are rewritten, so `--help` or a file name with dashes in it stays as written.
KEYWORDS: set = set()
_FLAG = re.compile(r"(?<![\w-])--([a-z][a-z0-9]*(?:-[a-z0-9]+)*)\b(?!-)")


def spelling() -> str:
    return SPELLING.get()


def spell(text: str) -> str:
    """`text` with each option flag (`--density-scale`) as the Python keyword
    (`density_scale=`) when the caller is Python; unchanged for the CLI."""
    if SPELLING.get() == "cli":
        return text

    def keyword(m):
        key = m.group(1).replace("-", "_")
        return f"{key}=" if key in KEYWORDS else m.group(0)
    return _FLAG.sub(keyword, text)


def option_name(key: str) -> str:
    """An option key (`density_scale`) as the caller spells it."""
    return "--" + key.replace("_", "-") if SPELLING.get() == "cli" else f"{key}="


def suggest(word: str, known, spell_as=str) -> str:
    """"did you mean X?" for the close matches of `word` among `known` ('' for none); a
    peer's spelling of an option (PEER_NAMES) names volrender's instead."""
    peer = peer_hint(word, spell_as)
    if peer:
        return peer
    close = difflib.get_close_matches(word, list(dict.fromkeys(known)), n=2, cutoff=0.6)
    if not close:
        return ""
    return "did you mean " + " or ".join(spell_as(c) for c in close) + "?"


# What peers call volrender's options (vdb_render's -res, -samples, -lookat, -translate;
# pbrt's pixelsamples and Mitsuba's sample_count; Blender's resolution): the option key each
# means here, and whose spelling it is. `suggest` names the option for them.
PEER_NAMES = {
    "res": ("size", "vdb_render's -res"), "resolution": ("size", "Blender's resolution"),
    "samples": ("spp", "vdb_render's -samples"), "pixelsamples": ("spp", "pbrt's pixelsamples"),
    "sample_count": ("spp", "Mitsuba's sample_count"), "samplecount": ("spp", "Mitsuba's sample_count"),
    "lookat": ("target", "vdb_render's -lookat"), "look_at": ("target", "a look-at point"),
    "translate": ("origin", "vdb_render's -translate"), "eye": ("origin", "a camera's eye"),
    "camera_position": ("origin", "a camera position"),
}


def peer_hint(word: str, spell_as=str) -> str:
    """"did you mean --size (vdb_render's -res)?" for a peer's spelling of an option ('' for
    none); `word` with or without dashes, in any case, with dashes or underscores."""
    key = word.lstrip("-").lower().replace("-", "_")
    hit = PEER_NAMES.get(key)
    if hit is None:
        return ""
    return f"did you mean {spell_as(hit[0])} ({hit[1]})?"


class UserError(ValueError):
    """An error caused by input or environment, reported without a traceback.

    A ValueError, so that Python callers can catch it as one (MissingFileError is also a
    FileNotFoundError). The CLI prints ``volrender: error: <message>`` and exits with
    status 2.
    Compose messages as ``"<file>: <problem>; <fix>"``. Non-printable characters (from
    file contents or names) are escaped (`printable`); subclasses that carry a log
    (device.BuildError) keep its line breaks.
    """
    multiline = False

    def __init__(self, message: str, *, path=None, fix: str | None = None):
        text = message
        if path is not None:
            text = f"{path}: {text}"
        if fix:
            text = f"{text}; {fix}"
        text = spell(text)
        if self.multiline:
            super().__init__("\n".join(printable(line) for line in text.split("\n")))
        else:
            super().__init__(printable(text))


class MissingFileError(UserError, FileNotFoundError):
    """A named input file that does not exist (also a FileNotFoundError)."""


class ImageWarning(UserWarning):
    """A rendered image that came out empty, a solid silhouette or overexposed (render()
    warns with it; the CLI prints it as `volrender: warning: ...`)."""


def one_line_if_uncaught(exc: BaseException) -> BaseException:
    """Make `exc`, should it reach the top of a script uncaught, print as the CLI prints
    errors (`volrender: error: ...`, no traceback); any other exception keeps the hook that
    was there. Returns exc (raise it)."""
    previous = sys.excepthook

    def hook(kind, value, tb):
        if value is exc:
            print(f"volrender: error: {value}", file=sys.stderr)
        else:
            previous(kind, value, tb)
    sys.excepthook = hook
    return exc


CL_OUT_OF_MEMORY = ("MEM_OBJECT_ALLOCATION_FAILURE", "OUT_OF_RESOURCES", "OUT_OF_HOST_MEMORY",
                    "INVALID_BUFFER_SIZE")


def opencl_message(exc) -> str | None:
    """A one-line message for an OpenCL error (None when exc is not one; pyopencl is not
    imported here: an error of it exists only once something else has imported it)."""
    cl = sys.modules.get("pyopencl")
    if cl is None or not isinstance(exc, cl.Error):
        return None
    text = " ".join(str(exc).split())
    try:
        code = exc.code
    except Exception:                       # an Error built without a status record
        code = None
    oom = {getattr(cl.status_code, n) for n in CL_OUT_OF_MEMORY if hasattr(cl.status_code, n)}
    if isinstance(exc, cl.MemoryError) or code in oom:
        return (f"the OpenCL device ran out of memory ({text}); render a smaller --size, fewer "
                "points or a smaller volume, or pick a device with more memory (--device)")
    return (f"OpenCL failed ({text}); try another --device, or rerun with --debug and report "
            "it as a volrender bug")
