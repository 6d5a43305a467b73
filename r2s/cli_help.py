"""Help text and usage errors of the command line (kept out of :mod:`r2s.cli`, which only
declares the commands).

- :func:`options_epilog`: the ``--set key=value`` options of a stage, from its pydantic
  options (type, default, description);
- :func:`tidy_help`: boolean flags show as ``--force``, not ``--force <bool>``, and a
  docstring's paragraphs are re-flowed (typer keeps the source's line breaks);
- :func:`usage_error`: a usage mistake (unknown command or option, missing argument) as one
  line and exit code 2, for typer's own exception classes and click's alike.
"""

from __future__ import annotations

import sys
from typing import Any, Optional

import typer


def _type_name(annotation: Any) -> str:
    name = getattr(annotation, "__name__", None)
    if name in ("bool",):
        return "true|false"
    if name is not None and getattr(annotation, "__args__", None) is None:
        return name
    text = str(annotation).replace("typing.", "")
    if text.startswith("Literal["):
        return "|".join(a.strip(" '\"") for a in text[len("Literal["):-1].split(","))
    return text


def options_epilog(stage_name: str) -> str:
    """``Options for --set key=value:`` then one paragraph per option of the stage."""
    from r2s.runner.registry import get_stage

    spec = get_stage(stage_name)
    lines = ["Options for --set key=value:\n\n"]
    for name, fld in spec.options_type.model_fields.items():
        default = fld.get_default(call_default_factory=True)
        shown = "none" if default is None else (str(default).lower() if isinstance(default, bool)
                                                else repr(default))
        lines.append(f"{name}=<{_type_name(fld.annotation)}> (default {shown}): "
                     f"{fld.description or ''}\n\n")
    return "".join(lines)


def reflow(text: str) -> str:
    """Join the lines of each paragraph (paragraphs are separated by blank lines)."""
    paragraphs = [" ".join(line.strip() for line in block.splitlines() if line.strip())
                  for block in text.strip().split("\n\n")]
    return "\n\n".join(p for p in paragraphs if p)


def tidy_help(command: Any) -> None:
    """For ``command`` and its subcommands: give every boolean flag an empty metavar, so
    help shows ``--json`` rather than ``--json <bool>`` (typer >= 0.20 prints the type),
    and re-flow the help text's paragraphs."""
    if isinstance(getattr(command, "help", None), str):
        command.help = reflow(command.help)
    for param in getattr(command, "params", []):
        if getattr(param, "is_flag", False):
            param.metavar = ""
    help_maker = getattr(command, "get_help_option", None)
    if help_maker is not None:
        try:
            ctx = typer.Context(command)
            option = help_maker(ctx)
            if option is not None and getattr(command, "_help_option", None) is option:
                option.metavar = ""  # cached per command (typer's vendored click)
        except Exception:  # noqa: BLE001 - cosmetic only; help still works without it
            pass
    for sub in getattr(command, "commands", {}).values():
        tidy_help(sub)


def _click_classes() -> tuple[tuple[type, ...], tuple[type, ...], tuple[type, ...]]:
    """(errors with a message, aborts, exits) of typer and, if loaded, click."""
    errors: list[type] = [typer.TyperException]
    aborts: list[type] = [typer.Abort]
    exits: list[type] = [typer.Exit]
    click = sys.modules.get("click")
    if click is not None:
        errors.append(click.exceptions.ClickException)
        aborts.append(click.exceptions.Abort)
        exits.append(click.exceptions.Exit)
    return tuple(errors), tuple(aborts), tuple(exits)


def usage_error(exc: BaseException) -> Optional[tuple[Optional[str], int]]:
    """``(one-line message or None, exit code)`` for the command line's own exceptions,
    None for anything else (a bug: keep its traceback)."""
    errors, aborts, exits = _click_classes()
    if isinstance(exc, exits):
        return None, int(getattr(exc, "exit_code", 0))
    if isinstance(exc, aborts):
        return "aborted", 1
    if not isinstance(exc, errors):
        return None
    ctx = getattr(exc, "ctx", None)
    if type(exc).__name__ == "NoArgsIsHelpError" and ctx is not None:
        print(ctx.get_help())  # ``r2s`` alone: the help, as a usage mistake (exit 2)
        return None, 2
    message = " ".join(str(exc.format_message()).split())
    if ctx is not None:
        message += f" (see '{ctx.command_path} --help')"
    return message, int(getattr(exc, "exit_code", 2))
