"""The command line's table of renamed flags, read before tyro parses.

A renamed flag is refused, not translated: a script that still passes the old name learns the new one in one
sentence (exit status 2) instead of running on with a spelling that may later mean something else.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import itertools
import re
import textwrap
import typing
from collections.abc import Sequence
from typing import Annotated, Any

import tyro

from digail.errors import UserError

RENAMED_FLAGS: dict[str, str] = {
    "--bc-weight": "--train.bc-weight",
    "--vae.codes": "--codes",
    # the discriminator's settings and the reward's names, gathered in `--train.imitation.*`
    "--train.disc-updates": "--train.imitation.disc-updates",
    "--train.disc-lr": "--train.imitation.disc-lr",
    "--train.disc-minibatch-size": "--train.imitation.disc-minibatch-size",
    "--train.disc-grad-penalty": "--train.imitation.disc-grad-penalty",
    "--train.sac.grad-penalty": "--train.imitation.disc-grad-penalty",
    "--train.sac.disc-every": "--train.imitation.disc-every",
    "--train.disc-obs": "--train.imitation.disc-obs",
    "--train.reward": "--train.imitation.logits-to-reward",
    "--train.imitation.kind": "--train.imitation.reward",
}
"""old flag -> the flag that replaced it, for every command (no command reuses an old name); a boolean's
`--...no-NAME` form is refused with its new `no-` form too"""


def _spelled(flag: str) -> str:
    """`flag` as the table spells it: tyro reads `--train.bc_weight` as `--train.bc-weight`."""
    return flag.replace("_", "-")


def _negated(flag: str) -> str:
    """The `no-` form of a boolean flag: `--train.shuffle-codes` -> `--train.no-shuffle-codes`."""
    head, _, name = flag[2:].rpartition(".")
    return "--" + (head + "." if head else "") + "no-" + name


def renamed(flag: str) -> str | None:
    """The flag that replaced `flag` (None when `flag` was not renamed)."""
    flag = _spelled(flag)
    if flag in RENAMED_FLAGS:
        return RENAMED_FLAGS[flag]
    for old, new in RENAMED_FLAGS.items():
        if flag == _negated(old):
            return _negated(new)
    return None


def refuse_renamed_flags(argv: Sequence[str]) -> None:
    """Raise a `UserError` naming the new flag when `argv` passes a renamed one (`RENAMED_FLAGS`)."""
    for tok in argv:
        if tok == "--":
            return
        if not tok.startswith("--"):
            continue
        flag = tok.partition("=")[0]
        new = renamed(flag)
        if new is not None:
            raise UserError(f"the flag {flag} is now {new}; pass {new} instead.")


HELP_ALL = "--help-all"
"""the flag that shows every setting of a command, the ones `--help` leaves out included"""

STUDY_SETTINGS: dict[str, tuple[str, ...]] = {
    "train": (
        # ablations and studies: switches whose only use is to measure what a part of the method contributes
        "train.shuffle_codes",
        "train.zero_code_weights",
        "train.bonus_code_entropy",
        "train.closed_loop_codes",
        "train.q_lr",
        "train.sac.absorbing",
        "train.imitation.ot_time_weight",
        "train.imitation.ot_code_penalty",
        "train.imitation.ot_top_k",
        "train.imitation.ot_iterations",
        # the optimisers' internals: their papers' constants and the warm-ups and floors that guard the start,
        # which the presets fix
        "train.bc_batch_size",
        "train.min_init_log_std",
        "train.value_warmup",
        "train.ppo.gamma",
        "train.ppo.gae_lambda",
        "train.ppo.clip",
        "train.ppo.vf_coef",
        "train.ppo.max_grad_norm",
        "train.ppo.norm_adv",
        "train.ppo.target_kl",
        "train.ppo.anneal_lr",
        "train.ppo.ent_coef",
        "train.sac.buffer_size",
        "train.sac.policy_lr",
        "train.sac.utd",
        "train.sac.gamma",
        "train.sac.tau",
        "train.sac.alpha_lr",
        "train.sac.init_alpha",
        "train.sac.learn_alpha",
        "train.sac.target_entropy",
        "train.sac.learning_starts",
        "train.sac.policy_warmup",
        "train.sac.hidden",
    ),
}
"""command -> the settings (field paths of its argument dataclass) that its `--help` leaves out: still flags,
listed by `--help-all` and in docs/reference/config.md"""


def flag_of(path: str) -> str:
    """The flag of a field path: `train.ppo.gae_lambda` -> `--train.ppo.gae-lambda`."""
    return "--" + path.replace("_", "-")


def without_flags(argv: Sequence[str], paths: Sequence[str]) -> list[str]:
    """`argv` without the flags of the settings at `paths` (a boolean's `no-` form too) and their values."""
    flags = {flag_of(p) for p in paths} | {_negated(flag_of(p)) for p in paths}
    out: list[str] = []
    dropping = False
    for tok in argv:
        if tok.startswith("-"):
            dropping = _spelled(tok.partition("=")[0]) in flags
        if not dropping:
            out.append(tok)
    return out


def help_view(cls: type, default: Any, hidden: Sequence[str]) -> tuple[type, Any]:
    """`cls` and its `default` as `--help` shows them: the same fields, those at the paths `hidden` marked
    `tyro.conf.Suppress`, each other one's help its docstring as one paragraph (`help_text`). Only for printing the
    help; parsing always uses `cls` itself."""
    view = _view(cls, set(hidden), "")
    return view, None if default is None else _as_view(default, view)


def field_docs(cls: type) -> dict[str, str]:
    """Each field's docstring (the string under it) in the class bodies of `cls` and its bases."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        except (OSError, TypeError):  # built in, or made at run time: no source
            continue
        body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
        for stmt, after in itertools.pairwise(body):
            if (isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name) and isinstance(after, ast.Expr)
                    and isinstance(after.value, ast.Constant) and isinstance(after.value.value, str)):
                docs[stmt.target.id] = after.value.value
    return docs


def help_text(doc: str) -> str:
    """A field docstring as `--help` prints it: its source lines joined (tyro keeps a line break wherever the next
    line of the docstring starts indented, which is every line of ours), blank-line paragraphs kept."""
    paragraphs = re.split(r"\n\s*\n", doc.strip())
    return "\n\n".join(" ".join(line.strip() for line in p.splitlines() if line.strip()) for p in paragraphs)


def _help_arg(doc: str) -> object:
    """The flag's help from its docstring; where the docstring says the default itself ("(default: the env's)"),
    without tyro's "(default: None)" after it."""
    text = help_text(doc)
    return tyro.conf.arg(help=text, help_behavior_hint="" if "(default:" in text else None)


def _view(cls: type, hidden: set[str], prefix: str) -> type:
    hints = typing.get_type_hints(cls, include_extras=True)
    docs = field_docs(cls)
    changed = []
    for f in dataclasses.fields(cls):
        path = prefix + f.name
        keep = dataclasses.field(default=f.default, default_factory=f.default_factory)
        if path in hidden:
            tp: Any = Annotated[hints[f.name], tyro.conf.Suppress]
            changed.append((f.name, tp, keep))
        elif dataclasses.is_dataclass(hints[f.name]):
            tp = _view(hints[f.name], hidden, path + ".")
            changed.append((f.name, tp, dataclasses.field(default_factory=tp)))
        elif f.name in docs:
            changed.append((f.name, Annotated[hints[f.name], _help_arg(docs[f.name])], keep))
    # a subclass: tyro finds each field's docstring on the class it was written in
    view = dataclasses.make_dataclass(cls.__name__, changed, bases=(cls,), frozen=True)
    view.__doc__ = cls.__doc__
    return view


def _as_view(value: Any, view: type) -> Any:
    """`value`, an instance of the class `view` was made from, as an instance of `view`."""
    hints = typing.get_type_hints(view, include_extras=True)
    kwargs = {}
    for f in dataclasses.fields(view):
        item, sub = getattr(value, f.name), hints[f.name]
        if isinstance(sub, type) and dataclasses.is_dataclass(item) and type(item) is not sub:
            item = _as_view(item, sub)
        kwargs[f.name] = item
    return view(**kwargs)
