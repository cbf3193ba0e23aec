"""User-facing errors: one line naming the file, the problem and the fix."""


class UserError(Exception):
    """An error caused by input or environment, reported without a traceback.

    The CLI prints ``volrender: error: <message>`` and exits with status 2.
    Compose messages as ``"<file>: <problem>; <fix>"``.
    """

    def __init__(self, message: str, *, path=None, fix: str | None = None):
        text = message
        if path is not None:
            text = f"{path}: {text}"
        if fix:
            text = f"{text}; {fix}"
        super().__init__(text)
