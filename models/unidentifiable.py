"""The refusal of values identification could not determine: a steering map or zone flagged
``identifiable: false`` in a parameter file (``params``: a :class:`~hmpc.models.params.Params`)
is refused by the tools that drive with it unless the user accepts it with a flag."""

from __future__ import annotations

from typing import Any

from hmpc.models.errors import ParamError

#: the command-line flag that accepts values flagged ``identifiable: false`` (named in the refusal)
ACCEPT_UNIDENTIFIABLE_FLAG = "--accept-unidentifiable"


def unidentifiable_keys(params: Any) -> list[tuple[str, str]]:
    """The parts of ``params`` that identification flagged ``identifiable: false``, as
    ``(key, note)`` pairs: ``("steering", note)`` and ``("longitudinal.zones[i]", note)``.
    An absent flag (a hand-written file) is not a refusal: only an explicit ``false`` is."""
    out = []
    if params.steering is not None and params.steering.identifiable is False:
        out.append(("steering", params.steering.note or ""))
    for i, z in enumerate(params.zones):
        if z.identifiable is False:
            out.append(
                (f"longitudinal.zones[{i}]", f"zone '{z.name}'" + (f": {z.note}" if z.note else ""))
            )
    return out


def check_identifiable(
    params: Any, *, accept: bool = False, flag: str = ACCEPT_UNIDENTIFIABLE_FLAG
) -> list[str]:
    """Refuse values the recording could not identify: a steering map or zone flagged
    ``identifiable: false`` raises :class:`ParamError` in one line naming the key(s) and
    ``flag``, the option that accepts them. With ``accept`` nothing is raised and one warning
    line naming every flagged key is returned for the caller to print."""
    bad = unidentifiable_keys(params)
    if not bad:
        return []
    if not accept:
        key, note = bad[0]
        note = f"{key}: {note}" if note else key
        if len(note) > 160:
            note = note[:157] + "..."
        raise ParamError(
            f"values flagged 'identifiable: false' ({note}); {flag} accepts them",
            params.path,
            key=", ".join(k for k, _ in bad),
        )
    where = params.path or "<params>"
    keys = ", ".join(f"'{k}'" for k, _ in bad)
    return [f"{where}: using values flagged 'identifiable: false' ({flag}) at {keys}"]
