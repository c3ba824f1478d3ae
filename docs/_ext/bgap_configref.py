"""Sphinx extension: bgap's configuration reference, generated from the schema dataclasses.

Every command's configuration is a tree of dataclasses (Hydra structured configs). The
directive ``bgap-schemas`` renders them, so the reference cannot drift from the code::

    .. bgap-schemas:: bgap.traffic.scenario bgap.traffic.behaviors

Each argument is a module (every public dataclass defined in it, in source order) or a
dotted class path. For each dataclass it writes a section with the class docstring, the
config group and presets it is selected by (``bgap/conf/<group>/*.yaml``), the commands
whose packaged config starts from it, and one entry per field: its type, its default and
its attribute docstring (the string literal right after the field, read with :mod:`ast`,
since Python keeps no such docstring at run time). Fields whose type is another rendered
schema link to it.
"""

from __future__ import annotations

import ast
import dataclasses
import importlib
import inspect
import pkgutil
import re
from functools import cache
from pathlib import Path
from typing import Any

import yaml
from docutils import nodes
from docutils.statemachine import StringList
from sphinx.application import Sphinx
from sphinx.util.docutils import SphinxDirective
from sphinx.util.nodes import nested_parse_with_titles

LABEL = "config-{}"


def label(cls: type) -> str:
    """The reference label of a schema's section (Sphinx lowercases labels)."""
    return LABEL.format(f"{cls.__module__}.{cls.__qualname__}").lower()


# --------------------------------------------------------------------------------------
# Reading the schemas


@cache
def _class_defs(module_name: str) -> dict[str, ast.ClassDef]:
    module = importlib.import_module(module_name)
    tree = ast.parse(Path(inspect.getfile(module)).read_text(encoding="utf-8"))
    return {n.name: n for n in tree.body if isinstance(n, ast.ClassDef)}


def attribute_docs(cls: type) -> tuple[str | None, dict[str, tuple[str, str | None]]]:
    """The class docstring and, per annotated field, (annotation source, docstring)."""
    node = _class_defs(cls.__module__)[cls.__name__]
    fields: dict[str, tuple[str, str | None]] = {}
    body = node.body
    for i, stmt in enumerate(body):
        if isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name):
            doc = None
            nxt = body[i + 1] if i + 1 < len(body) else None
            if (
                isinstance(nxt, ast.Expr)
                and isinstance(nxt.value, ast.Constant)
                and isinstance(nxt.value.value, str)
            ):
                doc = inspect.cleandoc(nxt.value.value)
            fields[stmt.target.id] = (ast.unparse(stmt.annotation), doc)
    return ast.get_docstring(node), fields


def module_schemas(module_name: str) -> list[type]:
    """Public dataclasses defined in a module, in source order."""
    module = importlib.import_module(module_name)
    found = [
        obj
        for name, obj in vars(module).items()
        if inspect.isclass(obj)
        and dataclasses.is_dataclass(obj)
        and obj.__module__ == module_name
        and not name.startswith("_")
    ]
    order = list(_class_defs(module_name))
    return sorted(found, key=lambda c: order.index(c.__name__) if c.__name__ in order else 1e9)


def resolve(target: str) -> list[type]:
    """A module's schemas, or the one class a dotted path names."""
    try:
        return module_schemas(importlib.import_module(target).__name__)
    except ModuleNotFoundError:
        module_name, _, cls_name = target.rpartition(".")
        if not module_name:
            raise
        cls = getattr(importlib.import_module(module_name), cls_name)
        if not dataclasses.is_dataclass(cls):
            raise TypeError(f"{target} is not a dataclass") from None
        return [cls]


@cache
def conf_dir() -> Path:
    import bgap

    return Path(bgap.__file__).resolve().parent / "conf"


@cache
def registered() -> dict[type, list[tuple[str | None, str]]]:
    """Schema -> its Hydra ConfigStore entries (group, name), from every ``SCHEMAS`` tuple
    that a ``config`` or ``params`` module of bgap declares."""
    import bgap

    entries: dict[type, list[tuple[str | None, str]]] = {}
    for info in pkgutil.walk_packages(bgap.__path__, "bgap."):
        if info.name.rpartition(".")[2] not in ("config", "params"):
            continue
        try:
            module = importlib.import_module(info.name)
        except Exception:  # a module being moved; its schemas are reported where rendered
            continue
        for group, name, schema in getattr(module, "SCHEMAS", ()):
            if (group, name) not in entries.setdefault(schema, []):
                entries[schema].append((group, name))
    return entries


@cache
def commands_by_schema() -> dict[str, list[tuple[str, str]]]:
    """Primary config name (``base_experiment``) -> [(command, yaml file)] whose defaults
    list names it."""
    found: dict[str, list[tuple[str, str]]] = {}
    for path in sorted(conf_dir().glob("*.yaml")):
        data = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
        app = ((data.get("hydra") or {}).get("help") or {}).get("app_name") or path.stem
        for entry in data.get("defaults") or []:
            if isinstance(entry, str):
                found.setdefault(entry, []).append((app, path.name))
    return found


def presets(group: str) -> list[str]:
    """The group's shipped presets: packaged, and the pipeline's (results/presets)."""
    from bgap.common.presets import group_options

    return group_options(group)


# --------------------------------------------------------------------------------------
# Rendering (reStructuredText, parsed in place)


def escape_bars(lines: list[str]) -> list[str]:
    """``|x|`` in prose (an absolute value) is a substitution in reStructuredText: escape
    the bars of every line that is not part of a table."""

    def escape(line: str) -> str:
        parts = line.split("``")  # odd parts are inline literals, where a bar is a bar
        return "``".join(p if i % 2 else p.replace("|", "\\|") for i, p in enumerate(parts))

    def table(line: str) -> bool:  # a grid table's row or border
        text = line.strip()
        return text[:1] in ("|", "+") and text[-1:] in ("|", "+")

    return [ln if table(ln) else escape(ln) for ln in lines]


def _literal(text: str) -> str:
    return "``" + text.replace("`", "'") + "``" if text else "``''``"


def _value(v: Any) -> str:
    """A value as a Hydra override would write it."""
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple)):
        return "[" + ",".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k}: {_value(x)}" for k, x in v.items()) + "}"
    return str(v)


def _default(f: dataclasses.Field, known: dict[str, type]) -> str:
    if f.default is not dataclasses.MISSING:
        if f.default == "???":  # OmegaConf's MISSING: the user must give it
            return "none (required)"
        return _literal(_value(f.default))
    if f.default_factory is dataclasses.MISSING:  # type: ignore[misc]
        return "required"
    value = f.default_factory()  # type: ignore[misc]
    if dataclasses.is_dataclass(value):
        cls = type(value)
        ref = f":ref:`{cls.__name__} <{label(cls)}>`" if cls in known.values() else cls.__name__
        try:
            plain = cls()
        except Exception:
            plain = None
        changed = [
            (g.name, getattr(value, g.name))
            for g in dataclasses.fields(cls)
            if plain is None or getattr(value, g.name) != getattr(plain, g.name)
        ]
        if not changed:
            return f"the {ref} defaults"
        return f"{ref} with " + ", ".join(_literal(f"{k}={_value(v)}") for k, v in changed)
    return _literal(_value(value))


def _type(annotation: str, known: dict[str, type]) -> str:
    if annotation in known:
        return f":ref:`{annotation} <{label(known[annotation])}>`"
    return _literal(annotation)


def render(cls: type, known: dict[str, type], underline: str) -> list[str]:
    doc, attrs = attribute_docs(cls)
    title = cls.__name__
    lines = [f".. _{label(cls)}:", "", title, underline * len(title), ""]
    lines += [f"``{cls.__module__}.{cls.__qualname__}``", ""]
    if doc:
        lines += [*escape_bars(normalise_docstring(doc.splitlines())), ""]

    about = []
    for group, name in registered().get(cls, []):
        if group is None:
            users = commands_by_schema().get(name, [])
            if users:
                cmds = ", ".join(f"``{app}`` (``conf/{yml}``)" for app, yml in users)
                about.append(f"The configuration of {cmds}.")
        else:
            names = presets(group)
            text = f"Config group ``{group}``"
            if names:
                text += ": presets " + ", ".join(f"``{group}={n}``" for n in names)
                text += f" (``bgap/conf/{group}/``, ``results/presets/{group}/``)"
            about.append(text + ".")
    bases = [b for b in cls.__bases__ if dataclasses.is_dataclass(b)]
    for base in bases:
        ref = f":ref:`{base.__name__} <{label(base)}>`" if base in known.values() else base.__name__
        about.append(f"Extends {ref}: every field of it, and these.")
    if about:
        lines += [*about, ""]

    inherited = {g.name for b in bases for g in dataclasses.fields(b)}
    by_name = {f.name: f for f in dataclasses.fields(cls)}
    own = [by_name[name] for name in attrs if name in by_name]  # in source order
    if not own:
        lines += ["No fields of its own.", ""]
    for f in own:
        annotation, fdoc = attrs[f.name]
        head = f"``{f.name}``: {_type(annotation, known)}, default {_default(f, known)}"
        if f.name in inherited:
            head += " (a new default for the inherited field)"
        lines.append(head)
        body = fdoc or (
            f"See :ref:`{annotation} <{label(known[annotation])}>`."
            if annotation in known
            else "(no description in the schema)"
        )
        body_lines = escape_bars(normalise_docstring(body.splitlines()))
        lines += ["    " + ln if ln.strip() else "" for ln in body_lines]
        lines.append("")
    return lines


class SchemasDirective(SphinxDirective):
    """``.. bgap-schemas:: MODULE_OR_CLASS ...`` (options: ``:underline:`` the section
    adornment character, ``~`` by default)."""

    required_arguments = 1
    optional_arguments = 50
    option_spec = {"underline": lambda s: (s or "~").strip()[:1]}

    def run(self) -> list[nodes.Node]:
        classes: list[type] = []
        for target in self.arguments:
            try:
                classes += [c for c in resolve(target) if c not in classes]
            except Exception as exc:
                raise self.error(f"bgap-schemas: cannot read {target}: {exc}") from exc
        known = {c.__name__: c for c in self._all_rendered()}
        known.update({c.__name__: c for c in classes})
        underline = self.options.get("underline", "~")
        text: list[str] = []
        for cls in classes:
            text += render(cls, known, underline)
        for module in {c.__module__ for c in classes}:  # rebuilt when a schema changes
            self.env.note_dependency(inspect.getfile(importlib.import_module(module)))
        container = nodes.container()
        source = self.get_source_info()[0]
        nested_parse_with_titles(self.state, StringList(text, source=source), container)
        return container.children

    def _all_rendered(self) -> list[type]:
        """Every schema any ``bgap-schemas`` directive of this document names, so that a
        field's type links to its section wherever that is rendered on the page."""
        source = Path(self.env.doc2path(self.env.docname)).read_text(encoding="utf-8")
        out: list[type] = []
        for line in source.splitlines():
            line = line.strip()
            if line.startswith(".. bgap-schemas::"):
                for target in line.split("::", 1)[1].split():
                    try:
                        out += resolve(target)
                    except Exception:
                        pass
        return out


_BULLET = re.compile(r"^(\s*)([-*+]|\d+[.)])\s+\S")
_LITERAL_GLUED = re.compile(r"(``[^`\s](?:[^`]*[^`\s])?``)(?=\w)")


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip())


def normalise_docstring(lines: list[str]) -> list[str]:
    """bgap's docstrings are written as plain text that mostly is reStructuredText. Three
    plain-text idioms are not, and are rewritten here (nothing else is touched):

    - a command sketch indented under a paragraph (a block quote) becomes a literal block;
    - a list that starts right under its lead-in line gets the blank line RST needs;
    - an inline literal glued to a word (````ignore````d) gets an escaped space.
    """
    out: list[str] = []
    in_literal = False
    literal_indent = 0
    for line in lines:
        prev = out[-1] if out else ""
        if in_literal:
            if line.strip() and _indent(line) <= literal_indent:
                in_literal = False
                if out and out[-1].strip():
                    out.append("")
            else:
                out.append(line)
                continue
        if not line.strip():
            out.append(line)
            continue
        # the last non-blank line before this one, and whether a blank line separates them
        j = len(out) - 1
        while j >= 0 and not out[j].strip():
            j -= 1
        last = out[j] if j >= 0 else ""
        blank_before = j < len(out) - 1
        m = _BULLET.match(last)
        text_start = len(m.group(1)) + len(m.group(2)) + 1 if m else _indent(last) if last else 0
        if last.rstrip().endswith("::") or last.lstrip().startswith(".."):
            in_literal = blank_before and _indent(line) > _indent(last)
            literal_indent = _indent(last)
            out.append(line)
            continue
        if blank_before and last and _indent(line) > text_start:
            out[len(out) :] = ["::", ""] if out[-1] == "" else ["", "::", ""]
            in_literal, literal_indent = True, _indent(last)
            out.append(line)
            continue
        if (
            _BULLET.match(line)
            and prev.strip()
            and not _BULLET.match(prev)
            and _indent(prev) == _indent(line)
            and not prev.lstrip().startswith(("|", ":"))
        ):
            out.append("")
        out.append(_LITERAL_GLUED.sub(lambda mm: mm.group(1) + "\\ ", line))
    return out


def _escape_docstring(app, what, name, obj, options, lines: list[str]) -> None:
    lines[:] = escape_bars(normalise_docstring(lines))


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_directive("bgap-schemas", SchemasDirective)
    app.connect("autodoc-process-docstring", _escape_docstring)
    return {"version": "1.0", "parallel_read_safe": True, "parallel_write_safe": True}
