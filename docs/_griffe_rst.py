"""A griffe extension for the API pages: pcreg's docstrings are written with reST roles
(``:func:`pcreg.register```) and ``name : description`` parameter lines; this turns the roles into
cross-references (links where the target is documented, code otherwise) and the parameter lines into
a list, so that mkdocstrings renders them as Markdown."""

from __future__ import annotations

import re
from typing import Any

import griffe

_ROLE = re.compile(r":(?:func|class|mod|meth|attr|data|exc|obj|const):`~?([^`<>]+?)`")
_PARAM = re.compile(r"^(\*{0,2}[A-Za-z_][\w]*(?:, \*{0,2}[A-Za-z_][\w]*)*) : (.*)$")
_SECTION = re.compile(r"^[A-Z][A-Za-z ]+\n-{3,}$", re.M)


def _resolve(target: str, obj: griffe.Object) -> str:
    """The full path of a role's target, relative names (``.steps``, ``~.config.X``, ``Frame``) included."""
    target = target.strip().rstrip("()")
    module = obj if isinstance(obj, griffe.Module) else obj.module
    package = module if module.is_package else module.parent
    if target.startswith("."):
        base = package
        target = target[1:]
        while target.startswith("."):
            base = base.parent if base.parent is not None else base
            target = target[1:]
        return f"{base.path}.{target}" if base is not None else target
    head = target.split(".", 1)[0]
    for scope in (obj, module, package):
        if scope is not None and head in getattr(scope, "members", {}):
            member = scope.members[head]
            path = member.target_path if member.is_alias else member.path
            return path + target[len(head):]
    return target


def _convert(text: str, obj: griffe.Object) -> str:
    def role(match: re.Match) -> str:
        raw = match.group(0)
        target = match.group(1)
        title = target.rsplit(".", 1)[-1] if "`~" in raw else target.lstrip(".")
        return f'<autoref identifier="{_resolve(target, obj)}" optional><code>{title}</code></autoref>'

    text = _ROLE.sub(role, text)
    if _SECTION.search(text):  # a numpydoc docstring: griffe's numpy parser reads its sections
        return text
    out: list[str] = []
    in_item = False
    in_fence = False
    for line in text.split("\n"):
        if line.lstrip().startswith("```"):
            in_fence = not in_fence
        match = None if in_fence else _PARAM.match(line)
        if match:
            if out and out[-1].strip() and not in_item:
                out.append("")
            out.append(f"- **{match.group(1)}** : {match.group(2)}")
            in_item = True
        elif in_item and line.startswith("    "):
            out.append("  " + line.strip())
        else:
            if in_item and line.strip():
                out.append("")
            in_item = False
            out.append(line)
    return "\n".join(out)


class RstRoles(griffe.Extension):
    """Converts every docstring of a package once it is loaded (relative names need its members)."""

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        stack: list[griffe.Object] = [pkg]
        while stack:
            obj = stack.pop()
            if obj.docstring is not None:
                obj.docstring.value = _convert(obj.docstring.value, obj)
            stack.extend(m for m in obj.members.values() if not m.is_alias)
