"""``crosscheck cases`` and ``crosscheck formalisms``: what there is to check, and with what."""

from __future__ import annotations

import cases
from crosscheck import backends
from crosscheck.cli.options import add_plugin_option


def cmd_cases(args) -> int:
    for info in cases.catalog():
        params = ", ".join(f"{k}={v}" for k, v in info.parameters.items()) or "no parameters"
        print(f"{info.name:18s} {info.summary}\n{'':18s} parameters: {params}")
    return 0


def cmd_formalisms(args) -> int:
    width = max(map(len, backends.names()))
    plugins = backends.plugin_sources()
    for name in backends.names():
        tag = " (external reference)" if name == backends.REFERENCE_NAME else ""
        tag = f" ({plugins[name]})" if name in plugins else tag
        formalism = backends.get(name)
        print(f"{name:{width}s}  {formalism.summary}{tag}")
        evaluation = getattr(formalism, "evaluation", None)  # a plugin need not have the field
        if evaluation is not None:
            print(f"{'':{width}s}  evaluation: {evaluation()}")
    return 0


def add_parser(sub) -> None:
    """The ``cases`` and ``formalisms`` subcommands on ``sub``."""
    sub.add_parser("cases", help="list the built-in cases and their parameters").set_defaults(run=cmd_cases)
    listing = sub.add_parser("formalisms", help="list the formalisms, the reference and the plugins")
    add_plugin_option(listing)
    listing.set_defaults(run=cmd_formalisms)
