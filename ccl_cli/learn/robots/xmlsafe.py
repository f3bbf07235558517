"""Reading robot description XML (URDF, MJCF) safely with the standard library.

The document is parsed by expat into an :class:`xml.etree.ElementTree.Element` tree; any
document type declaration is refused, so no entity is ever declared or expanded (no "billion
laughs", no external entity), and nothing is fetched. Robot descriptions never need a DTD.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from xml.parsers import expat

from ccl_cli.errors import InputError


class _Refused(Exception):
    """A document type declaration was found."""


def _refuse(*_args: object) -> None:
    raise _Refused


def parse_xml(text: str | bytes, source: str) -> ET.Element:
    """The root element of ``text``; :class:`InputError` naming ``source`` when the XML is not
    well formed or declares a document type or entities."""
    builder = ET.TreeBuilder()
    parser = expat.ParserCreate()
    parser.SetParamEntityParsing(expat.XML_PARAM_ENTITY_PARSING_NEVER)
    parser.StartDoctypeDeclHandler = _refuse
    parser.EntityDeclHandler = _refuse
    parser.StartElementHandler = builder.start
    parser.EndElementHandler = builder.end
    parser.CharacterDataHandler = builder.data
    parser.buffer_text = True
    try:
        parser.Parse(text, True)
    except _Refused:
        raise InputError(f"{source}: the XML declares a document type or entities (<!DOCTYPE ...>), "
                         "which a robot description does not need; remove it") from None
    except expat.ExpatError as e:
        raise InputError(f"{source}: not well-formed XML ({expat.errors.messages[e.code]} "
                         f"at line {e.lineno}, column {e.offset + 1})") from None
    return builder.close()


def read_xml(path: str | Path) -> ET.Element:
    """The root element of the XML file ``path`` (see :func:`parse_xml`)."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as e:
        raise InputError(f"{p}: cannot read ({e.strerror or e})") from None
    return parse_xml(data, str(p))


def floats(text: str | None, count: int, default: tuple[float, ...], what: str) -> tuple[float, ...]:
    """``count`` numbers from a whitespace-separated attribute, ``default`` when it is absent."""
    if text is None:
        return default
    try:
        values = tuple(float(v) for v in text.split())
    except ValueError:
        values = ()
    if len(values) != count or not all(abs(v) < float("inf") for v in values):
        raise InputError(f"{what}: {text!r} is not {count} finite numbers")
    return values
