"""What the library says, as data: findings and errors with the fixes they advise, worded here.

A quality check, a refusal or a warning that advises a fix is a :class:`Said`: a sentence with
named fields for its values and for each fix it advises (codes of :data:`FIXES`). The one
place that turns it into words is :meth:`Said.text`, for a Python caller (keywords:
``partial=True``) or a command-line user (flags: ``--partial``); a front end asks for its
wording and reads the fix codes (:attr:`Said.fixes`), never the words.
"""

from __future__ import annotations

import dataclasses
import string
from collections.abc import Mapping
from typing import Any

__all__ = ["FIXES", "AdvisedError", "OptionError", "Said", "named", "text_of"]

#: Each fix a message can advise: its Python wording and its command-line wording. A field
#: ``{partial}`` in a :class:`Said` template becomes one of them; ``{target_scale}`` reads the
#: ``factor`` value.
FIXES: Mapping[str, tuple[str, str]] = {
    # A map's own options are o3d_ofp.match's (a transfer takes its result as correspondence=).
    "landmarks": (
        "o3d_ofp.match(..., landmarks=[[source, target], ...])", "--landmarks 12:40,500:611"
    ),
    "landmarks_check": (
        "landmarks= of o3d_ofp.match; pick them with o3d_ofp.pick_landmarks",
        "--landmarks; pick them with --landmarks pick",
    ),
    "partial": ("o3d_ofp.match(..., partial=True)", "--partial"),
    "no_partial": ("match without partial=True", "match without --partial"),
    "closest": ("method='closest'", "--map closest"),
    "estimate": ("method='estimate'", "--map estimate"),
    "align": ("align=True", "--align"),
    "same_frame": ("o3d_ofp.match(..., options=MatchOptions(same_frame=True))", "--same-frame"),
    "no_shells": ("shells=False", "--no-shells"),
    "no_align": ("with align=False", "without --align"),
    "atlas": ("atlas=True", "--uv-atlas"),
    "texture": ("texture=...", "--texture FILE"),
    "replace_detail": ("mode='replace-detail'", "--mode replace-detail"),
    "band": ("band=30", "--band 30"),
    "coordinates_closest": (
        "mode='coordinates' with correspondence=o3d_ofp.match(..., method='closest')",
        "--mode coordinates --map closest",
    ),
    "smooth": ("filter_geometry(smooth=0.01)", "o3d-ofp filter --smooth 0.01"),
    "components_largest": (
        "components='largest' (to o3d_ofp.match, or to the eigenbases given as bases=)",
        "--components largest",
    ),
    "components_error": ("components='error'", "--components error"),
    "components_auto": ("components='auto'", "--components auto"),
    "target_scale": (
        "Open3D's target.scale({factor:g}, center=(0, 0, 0))",
        "--target-scale {factor:g}",
    ),
    "identity": ("map='identity'", "--map identity"),
    "cache": ("cache_dir=", "--cache"),
    "texture_size": ("kind='texture'", "--texture-size N"),
    "threshold": ("options=BasisOptions({setting})", "{flag}"),
    "default_threshold": (
        "preset={default!r}, the default for {task}",
        "--preset {default}, this command's default",
    ),
    "via_basis": ("via_basis=True", "--via-basis"),
    "pull_back": ("via_basis=False", "--pull-back"),
    "client": ("client=", "--scheduler"),
    "give_map": (
        "give the map (correspondence=o3d_ofp.Correspondence.from_p2p(p2p_21, source, target))",
        "give the map with --map FILE",
    ),
    # shapes that share their vertex order: the identity as the map, in a pair's own call
    "same_vertices": (
        "correspondence=o3d_ofp.Correspondence.from_p2p(numpy.arange({n}), source, target)",
        "--map identity",
    ),
    "lower": (
        "lower k1, k2 or order (options=BasisOptions(...))",
        "lower --k1/--k2 or --order",
    ),
    "lower_band": (
        "lower k1, k2 or order (options=BasisOptions(...)) or band",
        "lower --k1/--k2, --order or --band",
    ),
}


@dataclasses.dataclass(frozen=True)
class Said:
    """A message whose fixes are codes, worded for its reader by :meth:`text`.

    Attributes
    ----------
    template : str
        The sentence, :meth:`str.format` fields for ``values`` and for the fixes it advises
        (the keys of :data:`FIXES`).
    values : mapping
        The fields' values (numbers, names; JSON-serializable).
    code : str
        What was found or refused (e.g. ``"reversed"``, ``"looks_partial"``): front ends and
        tests read this, not the words.
    """

    template: str
    values: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    code: str = ""

    @property
    def fixes(self) -> tuple[str, ...]:
        """The codes of the fixes the message advises (its parts' too), in the order named."""
        found: list[str] = []
        for _, name, _, _ in string.Formatter().parse(self.template):
            value = self.values.get(name) if name else None
            if isinstance(value, Said):
                found.extend(value.fixes)
            elif name in FIXES and name not in self.values:
                found.append(name)
        return tuple(dict.fromkeys(found))

    def text(self, *, cli: bool = False) -> str:
        """Return the message for a Python caller, or (``cli``) for a command-line user."""
        values = {
            name: value.text(cli=cli) if isinstance(value, Said) else value
            for name, value in self.values.items()
        }
        words = {
            code: FIXES[code][cli].format(**values)
            for _, code, _, _ in string.Formatter().parse(self.template)
            if code in FIXES and code not in values
        }
        return self.template.format(**values, **words)

    def replace(self, **values: Any) -> Said:
        """Return the same message with some values replaced."""
        return dataclasses.replace(self, values={**self.values, **values})

    @classmethod
    def from_dict(cls, fields: Mapping[str, Any]) -> Said:
        """Rebuild a message from :func:`dataclasses.asdict` of one (its parts too)."""
        values = {
            name: cls.from_dict(v) if isinstance(v, Mapping) and "template" in v else v
            for name, v in fields.get("values", {}).items()
        }
        return cls(fields["template"], values, fields.get("code", ""))

    def __str__(self) -> str:
        return self.text()

    def __contains__(self, words: str) -> bool:
        """Whether its Python wording holds ``words`` (as the plain strings it replaces did)."""
        return words in self.text()


def named(name: str, message: str | Said) -> Said:
    """Return ``"<name>: <message>"`` as a Said (a message about one shape of several)."""
    if not isinstance(message, Said):
        message = Said(str(message).replace("{", "{{").replace("}", "}}"))
    return Said("{name}: {said}", {"name": name, "said": message}, message.code)


def text_of(message: Any, *, cli: bool = False) -> str:
    """Return the words of a :class:`Said`, of an exception carrying one, or ``str()``."""
    found = getattr(message, "said", message)
    return found.text(cli=cli) if isinstance(found, Said) else str(message)


class AdvisedError(ValueError):
    """A refusal that advises a fix: ``str()`` words it for Python, :func:`text_of` for a reader.

    Attributes
    ----------
    said : Said
        The message as data.
    """

    def __init__(self, message: Said) -> None:
        super().__init__(message.text())
        self.said = message

    def __reduce__(self) -> tuple[Any, ...]:
        # rebuilt from its Said, not its text: a forked job's refusal reaches the caller as
        # raised (pickled back from the child, it failed and read as the child lost)
        return (type(self), (self.said,), self.__dict__)


class OptionError(ValueError, TypeError):
    """An option refused where it was handed over: it names the keyword, the CLI its flag.

    Both a ValueError and a TypeError (a value of the wrong type is refused by the same
    check, with the same kind of message).

    Attributes
    ----------
    option : str
        The keyword (a field of an options object, or a function's parameter).
    problem : str or Said
        What is wrong with its value, after the name: ``"must be >= 1; got 0"`` (a Said when it
        advises a fix: :func:`text_of` words it for its reader).
    """

    def __init__(self, option: str, problem: str | Said) -> None:
        joint = "" if text_of(problem).startswith((":", ",", "=")) else " "
        self.said = Said(option + joint + "{problem}", {"problem": problem}, "option")
        super().__init__(self.said.text())
        self.option = option
        self.problem = problem

    def __reduce__(self) -> tuple[Any, ...]:
        return (type(self), (self.option, self.problem), self.__dict__)
