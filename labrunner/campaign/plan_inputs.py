"""The digest of everything a campaign's plan is computed from, so that ``resume`` can trust a
stored plan without planning every point again.

:func:`labrunner.campaign.spec.plan` is a pure function of the campaign file's content, the rig
file it names, the code it runs and numpy's (which evaluates the static checks). Planning costs
0.2–1 ms a point, so re-planning a 10^6-point campaign to check it on ``resume`` would take
minutes; comparing this digest, written into the ledger's ``meta`` at ``run``, takes milliseconds.
When it differs ``resume`` re-plans, compares the ids and the plan checksum, and — when they
match — writes the new digest, so that it re-plans once per change, not on every resume.

*The code it runs* is the import closure of :data:`PLAN_ROOTS` (:func:`code_files`), found by
reading the sources line by line (not importing them; ``ast`` took ~0.5 s, this ~20 ms): every module a planning module imports, at module
level or inside a function, and every ``"labrunner.module[:name]"`` string it holds (the rig-kind
and controller tables import those by name). A package whose submodule is imported contributes its
``__init__`` and what that imports at module level (not the lazy imports of its functions, which
run only when something names them — and that something is then in the closure itself); imports
under ``if TYPE_CHECKING:`` never run. An edit of such a file changes the digest; an edit of the
rest of labrunner (the analysis, the logs' reader, the command line, ...) does not. The list of
files is kept in ``meta`` beside the digest: the closure depends only on those files' contents, so
``resume`` hashes the same files again (~100 files, a few ms) rather than parsing the package.
Rig kinds and controllers registered from other packages are not hashed.
"""

from __future__ import annotations

import functools
import hashlib
import json
import re
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy

import labrunner

#: The ledger ``meta`` key holding :func:`digest` of the plan's inputs.
META_KEY = "plan_inputs"
#: The ledger ``meta`` key holding the code files (JSON list) that digest covers.
FILES_KEY = "plan_code_files"

#: The modules that load, validate and plan a campaign (``spec.load``, ``spec.from_text``, ``spec.plan``).
PLAN_ROOTS = ("labrunner.campaign.spec",)

_MODULE_NAME = re.compile(r"labrunner(?:\.\w+)+(?=:\w+$|$)")
_PACKAGE = Path(labrunner.__file__).resolve().parent


def _file(module: str) -> Path | None:
    """The source file of ``labrunner[.x.y]`` (a package's ``__init__.py``), None if none."""
    path = _PACKAGE.joinpath(*module.split(".")[1:])
    if (path / "__init__.py").is_file():
        return path / "__init__.py"
    return path.with_suffix(".py") if path.with_suffix(".py").is_file() else None


_IMPORT = re.compile(r"(?:from\s+(\.*[\w.]*)\s+import\s+(.*)|import\s+(.*))", re.S)
_BLOCK = re.compile(r"(?:if\s+(?:typing\.)?TYPE_CHECKING\s*:|(?:async\s+)?def\s)")
_STRING = re.compile(r"""["'](labrunner(?:\.\w+)+)(?::\w+)?["']""")


def _statements(text: str) -> Iterator[tuple[str, bool, bool]]:
    """(import statement, under ``if TYPE_CHECKING:``, inside a function) for each import in a
    source, read line by line, skipping triple-quoted strings: a block ends at the first line
    indented no deeper than its header. A line inside brackets can only end a block early, which
    adds imports, never drops one (a wider closure, never a narrower one)."""
    blocks: list[tuple[int, bool]] = []  # (indent, is TYPE_CHECKING) of open def / TYPE_CHECKING blocks
    quote = ""  # the delimiter of the triple-quoted string (a docstring) the line is in
    lines = iter(text.splitlines())
    for line in lines:
        stripped = line.lstrip()
        opened = quote
        for delimiter in ('"""', "'''"):
            if (not quote or quote == delimiter) and line.count(delimiter) % 2:
                quote = "" if quote else delimiter
        if opened or not stripped or stripped.startswith("#"):
            continue  # in a string (an example in a docstring is no import), blank, or a comment
        indent = len(line) - len(stripped)
        while blocks and blocks[-1][0] >= indent:
            blocks.pop()
        for part in stripped.split(";"):
            part = part.strip()
            if _BLOCK.match(part):
                blocks.append((indent, part.startswith("if")))
                while part.count("(") > part.count(")"):  # a signature over several lines
                    part += next(lines, ")")
            elif _IMPORT.match(part):
                while part.count("(") > part.count(")") or part.endswith("\\"):  # continued
                    part = part.rstrip("\\") + " " + next(lines, ")").strip()
                yield part, any(tc for _, tc in blocks), any(not tc for _, tc in blocks)


def _imports(module: str, text: str, whole: bool) -> set[str]:
    """Modules ``module`` imports (``whole``: also inside functions, and ``"labrunner.x:y"`` strings)."""
    found: set[str] = set()
    package = module if _file(module).name == "__init__.py" else module.rpartition(".")[0]  # type: ignore[union-attr]
    for statement, type_checking, in_function in _statements(text):
        if type_checking or (in_function and not whole):
            continue
        base, names, plain = _IMPORT.match(statement).groups()  # type: ignore[union-attr]
        if plain is not None:
            found.update(name.split()[0] for name in plain.split(",") if name.strip())
            continue
        if base.startswith("."):
            level = len(base) - len(base.lstrip("."))
            base = ".".join([*package.split(".")[: len(package.split(".")) - level + 1], base.lstrip(".")]).strip(".")
        for name in names.strip("() ").replace("\n", " ").split(","):
            name = name.split()[0] if name.strip() else ""
            if name and name != "*":  # a submodule by name, else a name the package defines
                found.add(f"{base}.{name}" if _file(f"{base}.{name}") else base)
            elif name == "*":
                found.add(base)
    if whole:
        found.update(_STRING.findall(text))
    return {name for name in found if name.split(".")[0] == "labrunner"}


@functools.cache
def code_files(roots: tuple[str, ...] = PLAN_ROOTS) -> tuple[str, ...]:
    """The source files (paths relative to the package, sorted) that planning may run (module docstring)."""
    whole: set[str] = set()
    init_only: set[str] = set()
    todo = [(root, True) for root in roots]
    while todo:
        module, full = todo.pop()
        if module in whole or (not full and module in init_only) or _file(module) is None:
            continue
        (whole if full else init_only).add(module)
        parts = module.split(".")
        todo += [(".".join(parts[:i]), False) for i in range(1, len(parts))]
        text = _file(module).read_text(encoding="utf-8")  # type: ignore[union-attr]
        todo += [(name, True) for name in _imports(module, text, full)]
    return tuple(sorted({_file(m).relative_to(_PACKAGE).as_posix() for m in whole | init_only}))  # type: ignore[union-attr]


def code_digest(files: Sequence[str]) -> str:
    """SHA-256 over numpy's version and ``files`` (relative path and bytes, in order; a missing
    file hashes as such): any edit of the code that plans changes it, with or without a version."""
    h = hashlib.sha256(f"numpy {numpy.__version__}\n".encode())
    for name in files:
        h.update(f"{name}\n".encode())
        path = _PACKAGE / name
        h.update(path.read_bytes() if path.is_file() else b"\0missing\0")
    return h.hexdigest()


def digest(campaign: Any, files: Sequence[str] | None = None) -> str:
    """SHA-256 of a :class:`~labrunner.campaign.spec.Campaign`'s plan inputs: its file parsed
    (so a comment or layout edit keeps it), its rig file validated, and :func:`code_digest` of
    ``files`` (default: :func:`code_files`)."""
    from labrunner.campaign.spec import parse

    inputs = {
        "campaign": parse(campaign.source, source_path=campaign.source_path),
        "rig": campaign.rig,
        "rig_path": str(campaign.rig_path) if campaign.rig_path else None,
        "rig_config": _located(campaign.rig_config.to_dict()),
        "code": code_digest(code_files() if files is None else files),
    }
    text = json.dumps(inputs, sort_keys=True, separators=(",", ":"), default=repr, ensure_ascii=False)
    return hashlib.sha256(text.encode()).hexdigest()


def _located(rig_config: dict[str, Any]) -> dict[str, Any]:
    """A rig configuration with its file named by its absolute path: the display path it keeps is
    relative to the working directory, which a ``resume`` from elsewhere does not share."""
    head = rig_config.get("rig", {})
    if head.get("source") and Path(head["source"]).is_file():
        rig_config = {**rig_config, "rig": {**head, "source": str(Path(head["source"]).resolve())}}
    return rig_config


def stamp(campaign: Any) -> dict[str, str]:
    """The ``meta`` entries that record the plan's inputs now (:data:`META_KEY`, :data:`FILES_KEY`)."""
    files = code_files()
    return {META_KEY: digest(campaign, files), FILES_KEY: json.dumps(files)}


def unchanged(campaign: Any, meta: Mapping[str, str]) -> bool:
    """Whether ``campaign``'s plan inputs are those recorded in ``meta`` (a ledger that kept no
    file list is compared with the closure as it is now)."""
    stored = meta.get(META_KEY)
    if stored is None:
        return False
    try:
        files = json.loads(meta[FILES_KEY]) if FILES_KEY in meta else None
    except ValueError:
        files = None
    return digest(campaign, files) == stored
