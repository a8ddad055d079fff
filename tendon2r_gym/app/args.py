"""Typed command lines, parsed one way: every console command and study is a dataclass of
typed fields parsed by tyro (cleanrl's Args); a command's main runs with one-line errors."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from typing import Any, TypeVar

A = TypeVar("A")


def arg(help: str) -> Any:  # noqa: A002
    """A field's --help text (tyro's marker, in ``Annotated[type, arg("...")]``)."""
    import tyro

    return tyro.conf.arg(help=help)


def env_help(name: str, note: str = "") -> Any:
    """The --help marker of a flag that is the env argument ``name``: its one description
    (the ``#:`` comment above its EnvConfig field, or the env docstring's ``Args:``;
    tendon2r_gym.app.field_docs), then what the command adds (``note``)."""
    from tendon2r_gym.app.field_docs import env_help as text

    return arg(text(name, note))


def parse(cls: type[A], argv: list[str] | None, doc: str | None = None) -> A:
    """Parses argv into the dataclass ``cls`` with tyro: one --flag per field, typed by its
    annotation (a bool is --flag / --no-flag, a list takes several values, a Literal its
    choices, ``X | None`` is optional)."""
    import tyro

    return tyro.cli(cls, args=argv, description=doc or cls.__doc__)


def run(main: Callable[[list[str] | None], Any]) -> Callable[[], None]:
    """Wraps a command's main: Ctrl-C exits 130, a ValueError is a one-line error (exit 2)."""

    def entry() -> None:
        os.environ.setdefault("MUJOCO_GL", "egl")
        try:
            main(None)
        except KeyboardInterrupt:
            print("interrupted", file=sys.stderr)
            sys.exit(130)
        except ValueError as e:
            print(f"error: {e}", file=sys.stderr)
            sys.exit(2)

    return entry
