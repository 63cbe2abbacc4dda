"""Shared pieces of the command-line tools (train.py, eval.py, `python -m match_jax.experiments`): an
argument parser whose errors end with the one line that matters, a check that an output path can be
written, made before any work, and the config-field flags (`--ppo.learning-rate`, `--env.break-force`)
that tyro derives from the config dataclasses."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import os
import pathlib
import re
import sys
import tempfile


class Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors print a one-line usage (`short_usage`, pointing to --help) and
    then the error line, instead of the usage of every option."""

    def __init__(self, *args, short_usage: str = "[options]", **kwargs):
        super().__init__(*args, **kwargs)
        self.short_usage = short_usage

    def error(self, message: str):
        sys.stderr.write(f"usage: {self.prog} {self.short_usage} (see --help)\n")
        self.exit(2, f"{self.prog}: error: {message}\n")


def unwritable(path: str | pathlib.Path, directory: bool = False) -> str | None:
    """Why `path` (a file; with directory=True a directory) cannot be written, or None if it can: a
    directory in a file's place, a file in a folder's place on the way, or a folder that takes no new
    files (probed by creating and removing a temporary file in the deepest folder that exists)."""
    path = pathlib.Path(path)
    place = path
    try:
        if path.exists():
            if directory and not path.is_dir():
                return f"{path} is a file, not a directory"
            if not directory and path.is_dir():
                return f"{path} is a directory"
            if not directory and not os.access(path, os.W_OK):
                return f"{path} is not writable"
        place = path if directory else path.parent
        while not place.exists() and place != place.parent:
            place = place.parent
        if not place.is_dir():
            return f"{place} is a file, not a directory"
        tempfile.NamedTemporaryFile(dir=place, prefix=".write_check_").close()
    except OSError as err:
        return f"cannot create files in {place} ({err.strerror or err})"
    return None


# Short names of the config fields users set most (train.py and the suite): each is the same as its
# --ppo.FIELD / --env.FIELD flag.
SHORT_NAMES = {f"--{path.rpartition('.')[2].replace('_', '-')}": path for path in (
    "ppo.num_envs", "ppo.rollout_steps", "ppo.epochs", "ppo.minibatches", "ppo.iterations_per_chunk",
    "ppo.learning_rate", "ppo.learning_rate_end", "ppo.desired_kl", "ppo.gamma", "ppo.gae_lambda", "ppo.ssl_coef",
    "ppo.network.actor_hidden", "ppo.network.actor_blocks", "ppo.network.critic_hidden",
    "ppo.network.critic_blocks", "ppo.network.initial_log_std", "ppo.network.initial_p_position",
    "ppo.network.initial_force_z", "env.break_force", "env.contact_timeconst", "env.break_sampling",
    "env.force_frame", "env.physics_backend")}
SHORT_NAMES["--spawn-noise"] = "env.spawn_noise_type"


class FieldError(ValueError):
    """A config-field flag that does not parse or that its config rejects; str() is one line."""


def _one_line(report: str) -> str:
    """The message of tyro's error report (title, rule, message lines, rule, ...) as one line, with
    its "Perhaps you meant" flags appended."""
    lines = [line.strip() for line in report.splitlines()]
    rules = [i for i, line in enumerate(lines) if line and set(line) <= set("-─")]
    body = lines[rules[0] + 1:rules[1]] if len(rules) >= 2 else [line for line in lines if line][1:2]
    message = " ".join(line for line in body if line)
    message = re.sub(r"^Error parsing ", "", re.sub(r"\s+", " ", re.sub(r"\[/?bold\]", "", message)))
    _, said, guesses = report.partition("Perhaps you meant:")
    guesses = re.findall(r"^\s*(--[a-z][\w.-]*)", guesses, flags=re.MULTILINE)
    if said and guesses:
        message += f" (did you mean {', '.join(dict.fromkeys(guesses))}?)"
    return message or report.strip()


def _spelled_for_tyro(tokens: list[str]) -> list[str]:
    """`tokens` with the values true / yes, false / no and none, in any case and in '--flag=value' too,
    written as tyro reads them (True, False, None)."""
    words = {"true": "True", "yes": "True", "false": "False", "no": "False", "none": "None"}
    spelled = []
    for token in tokens:
        flag, sep, value = token.partition("=") if token.startswith("--") else ("", "", token)
        value = words.get(value.lower(), value)
        spelled.append(f"{flag}={value}" if sep else value if not flag else token)
    return spelled


def _groups(defaults: dict[str, object]) -> type:
    """A frozen dataclass with one field per group of `defaults`, typed as that group's config."""
    return dataclasses.make_dataclass("ConfigFields", [(name, type(value)) for name, value in defaults.items()],
                                      frozen=True)


def parse_fields(defaults: dict[str, object], tokens: list[str], prog: str) -> dict[str, object]:
    """The frozen dataclass instances in `defaults` (group name -> instance) with the config-field flags in
    `tokens` applied: `--GROUP.FIELD VALUE`, nested as `--ppo.network.actor-hidden 256`, a tuple as its
    values one after another, True / False for booleans, None where a field may be None. tyro derives the
    flags from the dataclasses' fields, so each field is a flag with its type and comment as help. The
    configs' own checks run on the result; a bad flag or value raises FieldError with one line."""
    import tyro

    groups = _groups(defaults)
    report = io.StringIO()
    try:
        with contextlib.redirect_stderr(report), contextlib.redirect_stdout(report):
            parsed = tyro.cli(groups, default=groups(**defaults), args=_spelled_for_tyro(list(tokens)), prog=prog,
                              config=(tyro.conf.FlagConversionOff,))
    except SystemExit:
        raise FieldError(_one_line(report.getvalue())) from None
    return {name: getattr(parsed, name) for name in defaults}


def fields_help(defaults: dict[str, object], prog: str) -> str:
    """tyro's help for the config-field flags of `defaults` (as parse_fields takes them), the defaults shown
    being those instances' values."""
    import tyro

    groups = _groups(defaults)
    text = io.StringIO()
    with contextlib.redirect_stdout(text), contextlib.redirect_stderr(text):
        try:
            tyro.cli(groups, default=groups(**defaults), args=["--help"], prog=prog,
                     config=(tyro.conf.FlagConversionOff,))
        except SystemExit:
            pass
    # without tyro's own usage line and its -h option: the tool's parser has them
    return re.sub(r"\Ausage:.*?\n\s*\n\s*options\s*\n.*?\n\s*\n", "", text.getvalue(), flags=re.DOTALL)


def rewrite_short_names(tokens: list[str], short_names: dict[str, str]) -> list[str]:
    """`tokens` with each short flag of `short_names` (e.g. '--learning-rate' -> 'ppo.learning_rate') written
    as its config-field flag (--ppo.learning-rate), '--flag=value' included."""
    out = []
    for token in tokens:
        flag, sep, value = token.partition("=")
        if flag in short_names:
            out.append(field_flag(short_names[flag]))
            if sep:
                out.append(value)
        else:
            out.append(token)
    return out


def field_flag(path: str) -> str:
    """The flag of a config field 'group.field' (or 'group.sub.field'): --group.field-name."""
    return "--" + path.replace("_", "-")


def set_assignments(assignments: list[str], group: str) -> list[str]:
    """FIELD=VALUE assignments (`--set`) as config-field flags of `group`: 'network.head_scale=0.14' ->
    ['--ppo.network.head-scale', '0.14']."""
    tokens = []
    for assignment in assignments:
        name, sep, value = assignment.partition("=")
        if not sep or not name.strip():
            raise FieldError(f"--set expects FIELD=VALUE, got {assignment!r}")
        tokens += [field_flag(f"{group}.{name.strip()}"), *value.strip().split()]
    return tokens


def _is_value(token: str) -> bool:
    """Whether `token` can be one of a tuple field's values (a number or None)."""
    if token.lower() == "none":
        return True
    try:
        float(token)
    except ValueError:
        return False
    return True


def split_field_flags(argv: list[str], defaults: dict[str, object]) -> tuple[list[str], list[str]]:
    """(the other arguments, the config-field flags of the groups in `defaults` with their values) of
    `argv`. A flag takes one value, or '--flag=value'; a tuple field (or one that may be None) takes the
    numbers after it."""
    rest, fields, numbers, single_value = [], [], False, False
    for token in argv:
        flag, has_value, _ = token.partition("=")
        group, _, path = flag.removeprefix("--").partition(".")
        if token.startswith("--") and group in defaults and path:
            value = defaults[group]
            for name in path.replace("-", "_").split("."):
                value = getattr(value, name, None)
            numbers = not has_value and (value is None or isinstance(value, tuple))
            single_value = not has_value and not numbers
            fields.append(token)
        elif numbers and _is_value(token):
            fields.append(token)
        elif single_value:
            fields.append(token)
            single_value = False
        else:
            numbers = single_value = False
            rest.append(token)
    return rest, fields
