"""Meta-tests of the documentation site: the API reference (docs/reference/, built by mkdocstrings
from the docstrings) shows a curated, documented public API, and the mkdocs nav lists every page.

The reference is read with griffe, as mkdocstrings reads it: from the source, Google style."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("keymps", "keymps.plugin", "keymps.types", "keymps.primitives")
"""The packages with a page in docs/reference/: their `__all__` is the public API."""
UNDOCUMENTED_PARAMETERS = {"self", "cls"}


@pytest.fixture(scope="module")
def keymps_api() -> Any:
    griffe = pytest.importorskip("griffe", reason="the docs extra: pip install -e '.[docs]'")
    return griffe.load("keymps", search_paths=[str(REPO)], docstring_parser="google")


def _public(api: Any) -> Iterator[tuple[str, Any]]:
    """(dotted name, object) for every name in the packages' `__all__`, aliases resolved."""
    for package in PACKAGES:
        module = api if package == "keymps" else api[package.removeprefix("keymps.")]
        assert module.exports, f"{package} has no __all__"
        for name in module.exports:
            member = module[name]
            yield f"{package}.{name}", member.final_target if member.is_alias else member


def _callables(api: Any) -> Iterator[tuple[str, Any]]:
    """Public functions, and the public methods of public classes (properties excluded)."""
    for name, target in _public(api):
        if target.is_function:
            yield name, target
        elif target.is_class:
            yield name, target  # its __init__ parameters: documented in the class docstring
            for member_name, member in target.members.items():
                public = member.is_function and not member_name.startswith("_")
                if public and "property" not in member.labels:
                    yield f"{name}.{member_name}", member


def _sections(docstring: Any) -> dict[str, list[Any]]:
    parsed = docstring.parse("google") if docstring else []
    return {section.kind.value: section.value for section in parsed}


def _parameters(target: Any) -> list[str]:
    function = target
    if target.is_class:
        function = target.members.get("__init__")
        if function is None or function.is_alias or "dataclass" in target.labels:
            return []  # a dataclass's fields are documented one by one
    return [p.name for p in function.parameters if p.name not in UNDOCUMENTED_PARAMETERS]


def test_every_public_name_has_a_docstring(keymps_api: Any) -> None:
    missing = [name for name, target in _public(keymps_api) if not target.docstring]
    assert not missing, f"public names without a docstring: {missing}"


def test_keymps_types_exports_every_type_it_defines(keymps_api: Any) -> None:
    """keymps.types has no private part: a new stage result must reach the reference too."""
    module = keymps_api["types"]
    defined = {
        name
        for name, member in module.members.items()
        if not member.is_alias and not name.startswith("_") and name != "annotations"
    }
    assert defined == set(module.exports)


def test_classes_and_callables_open_with_a_one_line_summary(keymps_api: Any) -> None:
    """The reference's summary tables show a docstring's first line alone (PEP 257)."""
    run_on = []
    for name, target in [*_public(keymps_api), *_callables(keymps_api)]:
        lines = target.docstring.value.splitlines() if target.docstring else []
        if (target.is_class or target.is_function) and len(lines) > 1 and lines[1].strip():
            run_on.append(name)
    assert not run_on, f"a summary that runs on to a second line: {sorted(set(run_on))}"


def test_no_docstring_hides_a_placeholder_as_html(keymps_api: Any) -> None:
    """Markdown passes `<name>` through as an HTML tag, which the page then leaves out:
    placeholders such as runs/<name>-<time>/ belong in backticks."""
    code = re.compile(r"```.*?```|`[^`]*`", re.DOTALL)
    hidden = []
    for name, target in _public(keymps_api):
        members = target.members.items() if target.is_class else ()
        for label, item in [(name, target), *((f"{name}.{m}", v) for m, v in members)]:
            text = code.sub("", item.docstring.value) if item.docstring else ""
            if not item.is_alias and re.search(r"<[A-Za-z][\w-]*>", text):
                hidden.append(label)
    assert not hidden, f"docstrings with a bare <placeholder>: {hidden}"


def test_every_field_of_a_public_class_has_a_docstring(keymps_api: Any) -> None:
    """Dataclass fields and properties: the reference shows each with its shape and unit."""
    missing = []
    for name, target in _public(keymps_api):
        if not target.is_class:
            continue
        for member_name, member in target.members.items():
            if member_name.startswith("_") or member.is_alias:
                continue
            if member.labels & {"instance-attribute", "property"} and not member.docstring:
                missing.append(f"{name}.{member_name}")
    assert not missing, f"fields without a docstring: {missing}"


def test_public_callables_document_arguments_and_results(keymps_api: Any) -> None:
    """Google style: an Args entry per parameter, Returns when something is returned."""
    problems = []
    for name, target in _callables(keymps_api):
        sections = _sections(target.docstring)
        documented = {p.name.lstrip("*") for p in sections.get("parameters", [])}
        for parameter in _parameters(target):
            if parameter not in documented:
                problems.append(f"{name}: argument {parameter!r} not in Args")
        returns = str(target.returns) if target.is_function else "None"
        described = "returns" in sections or "yields" in sections
        if returns not in ("None", "NoReturn") and not described:
            problems.append(f"{name}: no Returns section")
    assert not problems, "\n".join(problems)


def test_the_reference_has_one_page_per_public_package() -> None:
    for package in PACKAGES:
        page = REPO / "docs/reference" / f"{package.rpartition('.')[2]}.md"
        assert f"::: {package}\n" in page.read_text(encoding="utf-8"), page


def _nav_pages(nav: Any) -> Iterator[str]:
    if isinstance(nav, str):
        yield nav
    elif isinstance(nav, list):
        for item in nav:
            yield from _nav_pages(item)
    elif isinstance(nav, dict):
        for value in nav.values():
            yield from _nav_pages(value)


def test_every_docs_page_is_in_the_nav_and_every_nav_page_exists() -> None:
    config = yaml.safe_load((REPO / "mkdocs.yml").read_text(encoding="utf-8"))
    assert config["docs_dir"] == "docs"
    listed = list(_nav_pages(config["nav"]))
    pages = sorted(str(p.relative_to(REPO / "docs")) for p in (REPO / "docs").rglob("*.md"))
    assert sorted(set(listed)) == pages
    assert len(listed) == len(set(listed)), "a page listed twice in the nav"
    assert listed[0] == "index.md", "docs/index.md is the front page"
