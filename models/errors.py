"""Error types of hmpc's input boundary, and the collector of recoverable problems.

Every reader raises :class:`InputError` for bad input that leaves nothing usable
(the CLI turns it into exit status 2 and a one-line reason), and records recoverable
problems (a malformed line, a frame that does not decode) in a :class:`Problems`
collector, which the CLI prints on stderr and writes to ``--json``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from collections.abc import Iterable


class HmpcError(Exception):
    """Base of every error hmpc raises on purpose."""


class InputError(HmpcError):
    """Bad input: names the file and, where it applies, the line, frame or channel.

    ``str(err)`` is the one-line reason the CLI prints, e.g.
    ``can.log:17: payload 'ZZ' is not hex``.
    """

    def __init__(
        self,
        reason: str,
        path: str | None = None,
        *,
        line: int | None = None,
        frame: int | None = None,
        channel: str | None = None,
        key: str | None = None,
    ):
        self.reason = reason
        self.path = None if path is None else str(path)
        self.line = line
        self.frame = frame
        self.channel = channel
        self.key = key
        super().__init__(self.one_line())

    def one_line(self) -> str:
        head = self.path or ""
        if head and self.line is not None:
            head += f":{self.line}"
        parts = [head] if head else []
        if self.line is not None and not head:
            parts.append(f"line {self.line}")
        elif self.line is None and self.frame is not None:
            parts.append(f"frame {self.frame}")
        if self.channel is not None:
            parts.append(f"channel '{self.channel}'")
        if self.key is not None:
            parts.append(f"key '{self.key}'")
        where = ": ".join(parts)  # never a leading ': ' when there is no file
        text = f"{where}: {self.reason}" if where else self.reason
        return " ".join(text.split())  # exactly one line


class ParamError(InputError):
    """A parameter or signal-map YAML file is malformed (unknown key, missing unit, bad value)."""


class SolverError(HmpcError):
    """An optimiser could not be set up (bad problem data).

    Solve failures are statuses, not this.
    """


@dataclass
class Problem:
    """One kind of recoverable problem, counted, with the first places it happened."""

    kind: str
    path: str
    count: int = 0
    first: list = field(default_factory=list)  # first line/frame numbers (1-based)
    detail: str = ""
    #: information, not a problem: normal on a real bus (e.g. frames of ids the DBC does not
    #: define); counted and reported apart, never in :meth:`Problems.total`.
    info: bool = False

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "file": self.path,
            "count": int(self.count),
            "first": [int(x) for x in self.first],
            "detail": self.detail,
        }


class Problems:
    """Collects recoverable problems: skipped, counted, reported with the first line numbers."""

    MAX_FIRST = 5

    def __init__(self) -> None:
        self._items: dict[tuple[str, str], Problem] = {}

    def add(
        self,
        kind: str,
        path: str,
        where: Iterable[int] | int | None = None,
        count: int | None = None,
        detail: str = "",
        info: bool = False,
    ) -> None:
        """Record ``count`` occurrences of ``kind`` in ``path`` at line/frame numbers ``where``;
        ``info=True`` for what is information rather than a problem (see :class:`Problem`)."""
        if where is None:
            places: list[int] = []
        elif isinstance(where, (int,)):
            places = [int(where)]
        else:
            places = [int(x) for x in where]
        n = len(places) if count is None else int(count)
        if n <= 0:
            return
        p = self._items.setdefault(
            (kind, str(path)), Problem(kind, str(path), detail=detail, info=info)
        )
        p.count += n
        room = self.MAX_FIRST - len(p.first)
        if room > 0:
            p.first.extend(places[:room])
        if detail and not p.detail:
            p.detail = detail

    def __len__(self) -> int:
        return len(self._items)

    def __iter__(self):
        return iter(self._items.values())

    def total(self) -> int:
        """Occurrences of real problems (information items not counted)."""
        return sum(p.count for p in self._items.values() if not p.info)

    def merge(self, other: Problems) -> None:
        for p in other:
            self.add(p.kind, p.path, p.first, count=p.count, detail=p.detail, info=p.info)

    def to_list(self) -> list[dict]:
        """The problems (information items are in :meth:`info_list`)."""
        return [p.to_dict() for p in self._items.values() if not p.info]

    def info_list(self) -> list[dict]:
        """The information items (e.g. frames whose ids the DBC does not define)."""
        return [p.to_dict() for p in self._items.values() if p.info]

    def lines(self) -> list[str]:
        """Human-readable one-liners for stderr; information items start with 'information:'."""
        out = []
        for p in sorted(self._items.values(), key=lambda q: q.info):
            first = ", ".join(str(x) for x in p.first)
            at = f" (first at {first})" if first else ""
            det = f": {p.detail}" if p.detail else ""
            tag = "information: " if p.info else ""
            out.append(f"{tag}{p.path}: {p.count} x {p.kind}{at}{det}")
        return out
