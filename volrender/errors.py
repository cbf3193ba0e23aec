"""User-facing errors: one line naming the file, the problem and the fix."""


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


class UserError(Exception):
    """An error caused by input or environment, reported without a traceback.

    The CLI prints ``volrender: error: <message>`` and exits with status 2.
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
        if self.multiline:
            super().__init__("\n".join(printable(line) for line in text.split("\n")))
        else:
            super().__init__(printable(text))
