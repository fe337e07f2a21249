"""The tolerant readers' tokenizer: a cursor over a text (tokens, lines, binary blocks) and number parsing with
messages that name the section and the line."""

from __future__ import annotations

import re

import numpy as np

from .common import ParseError

__all__ = ["Cursor", "numbers", "is_number"]


class Cursor:
    """Walks a text (a latin-1 decoded file: character offsets are byte offsets) by tokens, lines, bytes."""

    _TOKEN = re.compile(r"\S+")

    def __init__(self, raw: bytes, comment: str | None = None):
        self.raw = raw
        self.text = raw.decode("latin-1")
        self.n = len(self.text)
        self.pos = 0
        self.comment = comment

    def lineno(self, pos=None) -> int:
        return self.text.count("\n", 0, self.pos if pos is None else pos) + 1

    def _end(self, pos) -> int:
        e = self.text.find("\n", pos)
        return self.n if e < 0 else e

    def _seg(self, pos, end) -> str:
        seg = self.text[pos:end]
        if self.comment:
            i = seg.find(self.comment)
            if i >= 0:
                seg = seg[:i]
        return seg

    def token(self):
        """(next token, its offset) skipping whitespace and comments; (None, n) at the end."""
        while self.pos < self.n:
            e = self._end(self.pos)
            m = self._TOKEN.search(self._seg(self.pos, e))
            if m:
                start = self.pos + m.start()
                self.pos += m.end()
                return m.group(), start
            self.pos = e + 1
        return None, self.n

    def peek(self):
        save = self.pos
        tok = self.token()
        self.pos = save
        return tok

    def rest_of_line(self) -> str:
        e = self._end(self.pos)
        s = self.text[self.pos:e]
        self.pos = e + 1
        return s.strip()

    def next_line(self):
        """(next non-blank line stripped, its line number) or (None, None) at the end."""
        while self.pos < self.n:
            start = self.pos
            e = self._end(self.pos)
            s = self._seg(self.pos, e).strip()
            self.pos = e + 1
            if s:
                return s, self.lineno(start)
        return None, None

    def take(self, count: int) -> list:
        """The next ``count`` tokens (fewer at the end of the text)."""
        out = []
        while len(out) < count and self.pos < self.n:
            e = self._end(self.pos)
            seg = self._seg(self.pos, e)
            toks = seg.split()
            need = count - len(out)
            if len(toks) <= need:
                out.extend(toks)
                self.pos = e + 1
            else:
                for k, m in enumerate(self._TOKEN.finditer(seg)):
                    if k == need - 1:
                        self.pos += m.end()
                        break
                out.extend(toks[:need])
        return out

    def binary(self, count: int, dtype, what: str, line: int) -> np.ndarray:
        dtype = np.dtype(dtype)
        nbytes = count * dtype.itemsize
        if self.pos + nbytes > len(self.raw):
            have = max(len(self.raw) - self.pos, 0) // dtype.itemsize
            raise ParseError(f"expected {count} binary values for {what} (line {line}), "
                              f"found only {have} before the end of the file (truncated?)")
        arr = np.frombuffer(self.raw, dtype=dtype, count=count, offset=self.pos).copy()
        self.pos += nbytes
        if self.text.startswith("\r\n", self.pos):
            self.pos += 2
        elif self.text.startswith("\n", self.pos):
            self.pos += 1
        return arr


def numbers(tokens: list, count: int, dtype, what: str, line: int) -> np.ndarray:
    if len(tokens) < count:
        raise ParseError(f"expected {count} numbers for {what} (line {line}), "
                          f"found only {len(tokens)} before the end of the file (truncated?)")
    try:
        return np.array(tokens, dtype=dtype)
    except (ValueError, OverflowError):
        pass
    if np.dtype(dtype).kind in "iu":
        try:
            f = np.array(tokens, dtype=np.float64)
            if np.isfinite(f).all() and (f == np.round(f)).all():
                return f.astype(dtype)
        except (ValueError, OverflowError):
            pass
    conv = float if np.dtype(dtype).kind == "f" else int
    for t in tokens:
        try:
            conv(t)
        except (ValueError, OverflowError):
            kind = "a number" if conv is float else "an integer"
            raise ParseError(f"expected {kind} in the data of {what} (line {line}), found {t[:40]!r}") from None
    raise ParseError(f"could not convert the data of {what} (line {line})")  # pragma: no cover


def is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True
