"""The dict reads of records that were dicts (Image.info's RenderInfo, a sequence's
FrameRecord): `rec[key]`, `rec.get(key, default)` and `key in rec` still answer, with a
DeprecationWarning that names the attribute to read. A field that is None reads as a
missing key, as an absent key did."""
from __future__ import annotations

import dataclasses
import warnings

_MISSING = object()


class DictReads:
    """Mixin for a dataclass; WHAT names the record in the warnings ("Image.info")."""
    WHAT = "record"

    def _old(self, key, default=_MISSING):
        warnings.warn(f"{self.WHAT}[{key!r}] is deprecated: read {self.WHAT}.{key}",
                      DeprecationWarning, stacklevel=3)
        value = getattr(self, key, None) if key in _names(self) else None
        if value is None:
            if default is _MISSING:
                raise KeyError(key)
            return default
        return value

    def __getitem__(self, key):
        return self._old(key)

    def get(self, key, default=None):
        return self._old(key, default)

    def __contains__(self, key) -> bool:
        warnings.warn(f"`{key!r} in {self.WHAT}` is deprecated: read {self.WHAT}.{key}",
                      DeprecationWarning, stacklevel=2)
        return key in _names(self) and getattr(self, key) is not None


def _names(record) -> set:
    return {f.name for f in dataclasses.fields(record)}
