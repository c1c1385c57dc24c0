"""Sphinx extension of the huefringe manual: what is generated rather than typed.

- ``huefringe-config`` (directive): the table of every configuration key, walked from
  ``workflow/schemas/config.schema.yaml``, with its default from ``src/huefringe/defaults.yaml``
  and its documentation from the comments of ``defaults.yaml`` (then ``config.yaml``, then the
  schema's ``description``), so the page cannot drift from the files the workflow reads.
- ``<!-- huefringe:contents -->`` in ``index.md``: replaced, when the page is read, by one
  toctree per section of ``huefringe_sections`` (conf.py), each listing the pages of ``docs/``
  that match its patterns, and a last "More" toctree with every other top-level page, so a page
  another change adds under ``docs/`` appears without an edit here and none appears twice.
- ``optdoc`` (role): a link to a page that may not be in this checkout yet (``docs/capture.md``
  is written by other work): a ``doc`` cross-reference when the page exists, plain text naming
  the file otherwise, so a missing page never breaks a ``-W`` build.
"""

from __future__ import annotations

import fnmatch
import re
from pathlib import Path
from typing import Any

import yaml
from docutils import nodes
from docutils.parsers.rst import directives
from sphinx.application import Sphinx
from sphinx.util.docutils import SphinxDirective, SphinxRole

REPO = Path(__file__).resolve().parents[2]
SCHEMA = REPO / "workflow" / "schemas" / "config.schema.yaml"
DEFAULTS = REPO / "src" / "huefringe" / "defaults.yaml"
CONFIG = REPO / "config.yaml"
MARKER = "<!-- huefringe:contents -->"

_KEY = re.compile(r"^(?P<indent> *)(?P<key>[A-Za-z_][A-Za-z0-9_]*):(?P<rest>.*)$")
_COMMENT = re.compile(r"^(?P<indent> *)#\s?(?P<text>.*)$")


def yaml_comments(path: Path) -> dict[str, str]:
    """``dotted key -> its comment`` in a YAML file documented key by key.

    A key's comment is the comment at the end of its line, continued by comment-only lines
    indented deeper than the key right below it, or else the block of comment lines standing
    right above it at its own indentation (a blank line ends a block).

    Parameters
    ----------
    path : pathlib.Path
        YAML file (block style; flow-style values stay on their key's line).

    Returns
    -------
    dict of str to str
        Comments by dotted key path (``measurement.denoise_adaptive.max_radius``); keys
        without a comment are absent.
    """
    out: dict[str, str] = {}
    stack: list[tuple[int, str]] = []
    block: list[str] = []
    block_indent = -1
    last: tuple[str, int] | None = None  # the last key with a trailing comment, its indentation
    for line in path.read_text(encoding="utf-8").splitlines():
        if not line.strip():
            block, last = [], None
            continue
        c = _COMMENT.match(line)
        if c:
            indent = len(c["indent"])
            if last is not None and indent > last[1]:
                out[last[0]] += " " + c["text"].strip()
                continue
            last = None
            if block and indent != block_indent:
                block = []
            block_indent = indent
            block.append(c["text"].strip())
            continue
        k = _KEY.match(line)
        if not k:
            block, last = [], None
            continue
        indent = len(k["indent"])
        while stack and stack[-1][0] >= indent:
            stack.pop()
        stack.append((indent, k["key"]))
        dotted = ".".join(s[1] for s in stack)
        rest = k["rest"]
        # a trailing comment: " # text" outside quotes (the documented files quote no " # ")
        m = next((m for m in re.finditer(r"\s#", rest) if rest.count('"', 0, m.start()) % 2 == 0), None)
        if m:
            out[dotted] = rest[m.end():].strip()
            last = (dotted, indent)
        else:
            last = None
        if block and block_indent == indent and dotted not in out:
            out[dotted] = " ".join(block)
        block = []
    return out


def _lookup(tree: Any, dotted: str) -> tuple[bool, Any]:
    node = tree
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            return False, None
        node = node[part]
    return True, node


def _resolve(schema: dict[str, Any], node: dict[str, Any]) -> dict[str, Any]:
    ref = node.get("$ref")
    if isinstance(ref, str) and ref.startswith("#/"):
        target: Any = schema
        for part in ref[2:].split("/"):
            target = target[part]
        return {**target, **{k: v for k, v in node.items() if k != "$ref"}}
    return node


def _constraint(node: dict[str, Any]) -> str:
    if "enum" in node:
        return "one of " + ", ".join(_yaml_inline(v) for v in node["enum"])
    if "oneOf" in node:
        return " or ".join(_constraint(n) for n in node["oneOf"])
    kind = node.get("type", "")
    kind = " or ".join(kind) if isinstance(kind, list) else str(kind)
    if kind == "array" and isinstance(node.get("items"), dict):
        kind = f"list of {_constraint(node['items']) or 'values'}"
    bounds = []
    for key, sign in (("minimum", ">="), ("exclusiveMinimum", ">"), ("maximum", "<="), ("exclusiveMaximum", "<")):
        if key in node:
            bounds.append(f"{sign} {node[key]}")
    if "minLength" in node:
        bounds.append("non-empty")
    if "pattern" in node:
        bounds.append(f"matching {node['pattern']}")
    if "minItems" in node and kind.startswith("list"):
        bounds.append(f"at least {node['minItems']}")
    return ", ".join([kind] + bounds) if kind else ", ".join(bounds)


def _yaml_inline(value: Any) -> str:
    return yaml.safe_dump(value, default_flow_style=True, width=10_000).strip().removesuffix("...").strip()


def config_rows() -> list[tuple[str, str, str, str, bool]]:
    """The configuration reference: ``(key, allowed values, default, documentation, required)``.

    One row per key of the schema, depth first in the schema's order, nested keys dotted.

    Returns
    -------
    list of tuple
        ``(dotted key, constraint, default as YAML or "", documentation, required)``.
    """
    schema = yaml.safe_load(SCHEMA.read_text(encoding="utf-8"))
    defaults = yaml.safe_load(DEFAULTS.read_text(encoding="utf-8"))
    notes = {**yaml_comments(CONFIG), **yaml_comments(DEFAULTS)}
    rows: list[tuple[str, str, str, str, bool]] = []

    def walk(node: dict[str, Any], prefix: str) -> None:
        required = set(node.get("required", []))
        for key, child in node.get("properties", {}).items():
            child = _resolve(schema, child)
            dotted = f"{prefix}{key}"
            has, value = _lookup(defaults, dotted)
            is_object = child.get("type") == "object" and "properties" in child
            if has and not is_object:
                default = _yaml_inline(value)
            elif "default" in child:
                default = _yaml_inline(child["default"])
            else:
                default = ""
            doc = notes.get(dotted) or str(child.get("description", "")).strip()
            rows.append((dotted, "section" if is_object else _constraint(child), default, doc, key in required))
            if is_object:
                walk(child, dotted + ".")

    walk(schema, "")
    return rows


def _cell(*children: nodes.Node) -> nodes.entry:
    entry = nodes.entry()
    entry += nodes.paragraph("", "", *children)
    return entry


def _text_with_code(text: str) -> list[nodes.Node]:
    """Plain text with ``backtick`` spans as inline literals."""
    out: list[nodes.Node] = []
    for i, part in enumerate(re.split(r"`([^`]*)`", text)):
        if part:
            out.append(nodes.literal(part, part) if i % 2 else nodes.Text(part))
    return out


class ConfigTable(SphinxDirective):
    """``huefringe-config``: the table of every configuration key (see the module's docstring)."""

    has_content = False
    option_spec = {"class": directives.class_option}

    def run(self) -> list[nodes.Node]:
        for path in (SCHEMA, DEFAULTS, CONFIG):
            self.env.note_dependency(str(path))
        headers = ("key", "allowed values", "default", "what it does")
        table = nodes.table(classes=["huefringe-config"])
        group = nodes.tgroup(cols=len(headers))
        table += group
        for width in (22, 22, 14, 42):
            group += nodes.colspec(colwidth=width)
        head = nodes.thead()
        row = nodes.row()
        for h in headers:
            row += _cell(nodes.Text(h))
        head += row
        group += head
        body = nodes.tbody()
        for key, constraint, default, doc, required in config_rows():
            row = nodes.row(ids=[nodes.make_id("config-" + key)])
            name = [nodes.literal(key, key)]
            if required:
                name.append(nodes.Text(" (required)"))
            row += _cell(*name)
            row += _cell(*_text_with_code(constraint))
            row += _cell(nodes.literal(default, default)) if default else _cell(nodes.Text(""))
            row += _cell(*_text_with_code(doc))
            body += row
        group += body
        return [table]


def contents_markdown(found: set[str], sections: list[tuple[str, list[str]]]) -> str:
    """The toctrees replacing :data:`MARKER` in ``index.md``.

    Parameters
    ----------
    found : set of str
        The docnames Sphinx found (``env.found_docs``).
    sections : list of (str, list of str)
        ``(caption, docname patterns)``; a page goes to the first section whose pattern matches it,
        in the order of the patterns, then alphabetically within one pattern.

    Returns
    -------
    str
        MyST toctree directives; the last, "More", holds every top-level page no pattern named.
    """
    taken = {"index"}
    blocks = []
    for caption, patterns in sections:
        pages: list[str] = []
        for pattern in patterns:
            for doc in sorted(fnmatch.filter(found, pattern)):
                if doc not in taken:
                    pages.append(doc)
                    taken.add(doc)
        if pages:
            blocks.append((caption, pages))
    rest = sorted(d for d in found - taken if "/" not in d)
    if rest:
        blocks.append(("More", rest))
    out = []
    for caption, pages in blocks:
        out.append("```{toctree}\n:caption: " + caption + "\n:maxdepth: 1\n\n" + "\n".join(pages) + "\n```\n")
    return "\n".join(out)


def _source_read(app: Sphinx, docname: str, source: list[str]) -> None:
    if docname == app.config.root_doc and MARKER in source[0]:
        source[0] = source[0].replace(MARKER, contents_markdown(set(app.env.found_docs), app.config.huefringe_sections))


class OptionalDoc(SphinxRole):
    """``optdoc``: ``{optdoc}`title <page>``` links ``page`` when this build has it, else names the file."""

    def run(self) -> tuple[list[nodes.Node], list[nodes.system_message]]:
        m = re.fullmatch(r"\s*(?:(?P<title>.*?)\s*<(?P<target>[^<>]+)>|(?P<bare>[^<>]+))\s*", self.text)
        if not m:
            msg = self.inliner.reporter.error(f"optdoc: cannot read {self.text!r}", line=self.lineno)
            return [], [msg]
        target = (m["target"] or m["bare"]).strip().removesuffix(".md")
        title = (m["title"] or target).strip()
        if target in self.env.found_docs:
            role = self.env.get_domain("std").role("doc")
            assert role is not None
            return role("doc", self.rawtext, f"{title} <{target}>", self.lineno, self.inliner, {}, [])
        text = f"{title} (docs/{target}.md, not in this checkout yet)"
        return [nodes.emphasis(text, text)], []


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_config_value("huefringe_sections", [], "env", types=[list])
    app.add_directive("huefringe-config", ConfigTable)
    app.add_role("optdoc", OptionalDoc())
    app.connect("source-read", _source_read)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
