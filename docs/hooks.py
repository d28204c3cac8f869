"""MkDocs hook: fills the generated tables of the documentation from the code.

In a page, a comment marker is replaced by a Markdown table (qdrl.docgen):

    <!-- keys qdrl.algorithms.qd:RepertoireConfig repertoire -->   the keys of [repertoire]
    <!-- tasks -->                                              the task catalogue
    <!-- specs map_elites_ cvt_map_elites_ -->                  the packaged specs by prefix
"""

from __future__ import annotations

import importlib
import re
from typing import Any

_MARKER = re.compile(r"<!-- (keys|tasks|specs)\b([^>]*)-->")


def _table(kind: str, args: list[str]) -> str:
    from qdrl import docgen

    if kind == "keys":
        target, section = args
        module, name = target.split(":")
        return docgen.keys_table(getattr(importlib.import_module(module), name), section)
    if kind == "tasks":
        return docgen.tasks_table(args or None)
    return docgen.specs_table(args)


def on_page_markdown(markdown: str, **kwargs: Any) -> str:
    return _MARKER.sub(lambda m: _table(m.group(1), m.group(2).split()), markdown)
