"""The one YAML reader for what users write (mission text on the page, scenario, fleet and
command files): YAML without anchors and aliases (pure).

An alias is a reference: ``a: &x [...]`` then ``b: [*x, *x, ...]`` costs a few characters per
level and multiplies the data tenfold per level once it is serialised (JSON has no references):
six hundred characters became gigabytes (issue 23). Nothing we read needs them, so an anchor or an
alias is refused where it stands, and nesting too deep for the parser is a `yaml.YAMLError` like
any other bad YAML rather than a crash.
"""

from __future__ import annotations

from typing import Any

import yaml
from yaml.composer import ComposerError
from yaml.nodes import Node


class _NoAliasLoader(yaml.SafeLoader):
    """`yaml.SafeLoader` that refuses every anchor (``&x``) and alias (``*x``), merge keys
    (``<<: *x``) included."""

    def compose_node(self, parent: Node | None, index: Any) -> Node | None:
        event = self.peek_event()  # type: ignore[no-untyped-call]
        if isinstance(event, yaml.AliasEvent) or getattr(event, "anchor", None) is not None:
            raise ComposerError(None, None, "anchors and aliases (&name, *name) are not accepted",
                                event.start_mark)
        return super().compose_node(parent, index)


def load_yaml(text: str | bytes) -> Any:
    """One YAML document as plain data, as `yaml.safe_load` reads it, but without anchors or
    aliases; `yaml.YAMLError` for anything else it cannot read."""
    try:
        return yaml.load(text, Loader=_NoAliasLoader)  # a SafeLoader
    except RecursionError:
        raise yaml.YAMLError("nested too deeply") from None
