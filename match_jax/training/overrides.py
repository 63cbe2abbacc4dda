"""FIELD=VALUE assignments to a PPOConfig, parsed by the field's type: every learning setting is settable
from the command line without a flag of its own (`train.py --set critic_steps=2 network.head_scale=0.14`).

A name is a PPOConfig field or `network.` and a NetworkConfig field. Values: numbers ('1e-5', 'inf'),
'true' / 'false' for booleans, 'none' where the field may be None, words for the string fields. The
config's own checks run on the result, so a bad value ends in their one-line error.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing

from match_jax.rl.networks import NetworkConfig
from match_jax.rl.ppo import PPOConfig

NOT_SETTABLE = ("network",)  # a whole NetworkConfig: set its fields as network.FIELD


def _parse(text: str, hint, name: str):
    """`text` as a value of type `hint` (int, float, bool, str, or one of them | None)."""
    args = typing.get_args(hint)
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        if text.lower() == "none" and type(None) in args:
            return None
        hint = next(a for a in args if a is not type(None))
    if hint is bool:
        if text.lower() in ("true", "1", "yes"):
            return True
        if text.lower() in ("false", "0", "no"):
            return False
        raise ValueError(f"--set {name}: expected true or false, got {text!r}")
    if hint is int:
        try:
            return int(text)
        except ValueError:
            raise ValueError(f"--set {name}: expected an integer, got {text!r}") from None
    if hint is float:
        try:
            value = float(text)
        except ValueError:
            raise ValueError(f"--set {name}: expected a number, got {text!r}") from None
        if math.isnan(value):
            raise ValueError(f"--set {name}: expected a number, got {text!r}")
        return value
    return text


def settable_fields() -> dict[str, typing.Any]:
    """Every name `apply_overrides` accepts, with its type."""
    ppo = typing.get_type_hints(PPOConfig)
    network = typing.get_type_hints(NetworkConfig)
    names = {name: hint for name, hint in ppo.items() if name not in NOT_SETTABLE}
    names.update({f"network.{name}": hint for name, hint in network.items()})
    return names


def apply_overrides(ppo: PPOConfig, assignments: typing.Iterable[str]) -> PPOConfig:
    """`ppo` with each FIELD=VALUE (or network.FIELD=VALUE) assignment applied, in order."""
    fields = settable_fields()
    top, network = {}, {}
    for assignment in assignments:
        name, sep, text = assignment.partition("=")
        name = name.strip().replace("-", "_")
        if not sep or not name:
            raise ValueError(f"--set expects FIELD=VALUE, got {assignment!r}")
        if name not in fields:
            raise ValueError(f"--set: unknown field {name!r}; settable: {', '.join(sorted(fields))}")
        value = _parse(text.strip(), fields[name], name)
        if name.startswith("network."):
            network[name.removeprefix("network.")] = value
        else:
            top[name] = value
    if network:
        top["network"] = dataclasses.replace(ppo.network, **network)
    return dataclasses.replace(ppo, **top) if top else ppo
