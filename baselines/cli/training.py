"""``scripts/train.py``'s command line, before Hydra starts and writes anything: every job of a sweep composed and
checked (:func:`check_command_line`; one line naming a bad key or value, exit status 2), and ``--help``
(:func:`help_text`: the groups, then every key of the composed config with its type, default and the meaning its
config file gives it).  The other scripts' ``key=value`` command lines are :mod:`evaaa_baselines.cli`'s.
"""

from __future__ import annotations

import copy
import re
import sys
import tempfile
import textwrap
from pathlib import Path
from typing import Any

from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import DictConfig, OmegaConf, open_dict

from evaaa.records import DiskError

from ..config import (
    FREE_FORM,
    GROUP_KEYS,
    NOT_TRAINING,
    NULLABLE,
    ConfigError,
    check_level_file,
    compose_checked,
    group_choice,
    last_composed,
    one_line,
    register_levels,
    show,
    typed_values,
    validate,
)
from ..paths import CONF_DIR


def job_overrides(overrides: list[str], multirun: bool) -> list[list[str]]:
    """The override lists of the jobs to check: one, or for a sweep (``-m seed=0,1 algo=dqn,ppo``) each value of each
    swept key once (the others at their first value), so that every value given is composed and checked."""
    from hydra.errors import OverrideParseException

    try:
        parsed = OverridesParser.create().parse_overrides(overrides)
    except OverrideParseException as err:
        raise ConfigError(f"{one_line(err)} (in {' '.join(overrides)}; lists are key=[a,b])") from None
    swept = {i: list(o.sweep_string_iterator()) for i, o in enumerate(parsed) if o.is_sweep_override()}
    if swept and not multirun:
        first = parsed[next(iter(swept))]
        raise ConfigError(
            f"{first.input_line}: several values make a sweep: add -m (--multirun); a list is "
            f"written {first.key_or_group}=[a,b]"
        )
    if not swept:
        return [list(overrides)]

    def line(i: int, value: str) -> str:
        return f"{parsed[i].get_key_element()}={value}"

    base = [
        line(i, values[0]) if i in swept else o.input_line
        for i, (o, values) in enumerate((o, swept.get(i, [])) for i, o in enumerate(parsed))
    ]
    jobs = [base]
    for i, values in swept.items():
        for value in values[1:]:
            jobs.append([*base[:i], line(i, value), *base[i + 1 :]])
    return jobs


def check_overrides(overrides: list[str], multirun: bool, values: bool = True) -> None:
    """Compose and check every job of :func:`job_overrides`; a job that differs from the first only in the value of
    a plain key (``seed=0,1,2``) is checked by setting that value in the first job's config, which is much faster
    than composing it again and gives the same verdict.  ``values=False``: keys and types only, not what depends on
    this machine (:func:`check_values`).  Raises :class:`ConfigError`."""
    jobs = job_overrides(overrides, multirun)
    compose_checked(jobs[0], values)
    first, defaults = last_composed()
    from hydra.core.global_hydra import GlobalHydra

    groups = set(GlobalHydra.instance().config_loader().list_groups(""))
    parser = OverridesParser.create()
    for job in jobs[1:]:
        changed = [parser.parse_override(new) for new, old in zip(job, jobs[0]) if new != old]
        if len(changed) != 1 or group_choice(changed[0], groups) or changed[0].key_or_group.startswith("hydra"):
            compose_checked(job, values)
            continue
        trial = copy.deepcopy(first)
        with open_dict(trial):
            OmegaConf.update(trial, changed[0].key_or_group, changed[0].value(), force_add=True)
        validate(trial, defaults, typed=typed_values(changed))
        if values:  # -m level.file=a.yaml,b.yaml: each file is read and checked
            check_level_file(trial)


def check_command_line(argv: list[str], doc: str = "") -> None:
    """``scripts/train.py``'s command line, before Hydra starts (and writes anything): ``--help`` prints
    :func:`help_text` and exits 0; a malformed value, unknown key or option prints one line naming it and exits 2.
    Every job of a sweep is composed and checked.  Hydra's other flags are Hydra's (``--hydra-help``, ``--info``)."""
    from hydra import initialize_config_dir
    from hydra._internal.utils import get_args_parser

    register_levels()
    args = get_args_parser().parse_args(argv)  # Hydra's own flags, parsed as Hydra will (a bad flag exits 2 here)
    if args.hydra_help or args.info or args.shell_completion or args.config_name or args.config_path or args.config_dir:
        return  # Hydra's own answers, or another config than conf/config.yaml: Hydra checks it
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        try:
            if args.help:
                print(help_text(args.overrides, "train.py", doc.split("\n\n")[0].replace("``", "")))
                raise SystemExit(0)
            check_overrides(args.overrides, args.multirun)
        except ConfigError as err:
            print(f"train.py: error: {err}", file=sys.stderr)
            raise SystemExit(2) from None
    root = Path(str(OmegaConf.select(last_composed()[0], "run.root", default="runs")))
    try:
        check_writable(root)
    except DiskError as err:  # Hydra would make the run folder and end in a traceback
        print(f"train.py: {err}; nothing was written", file=sys.stderr)
        raise SystemExit(1) from None


def check_writable(folder: Path) -> None:
    """Raise :class:`~evaaa.records.DiskError` where ``folder`` (or, while it does not exist, the folder it would
    be made in) cannot take files: a real write, since root passes every permission check on a read-only disk."""
    existing = folder
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    try:
        with tempfile.TemporaryDirectory(dir=existing, prefix=".write-test-"):
            pass
    except OSError as exc:
        raise DiskError(folder, exc) from None


_LINE = re.compile(r"^(?P<indent>\s*)(?P<key>[\w.-]+):(?P<rest>.*)$")


def comments(path: Path, prefix: str) -> dict[str, str]:
    """The trailing ``# comment`` of every ``key: value`` line of a YAML config file, by dotted key (``prefix`` is
    the file's package: ``algo.`` for conf/algo/*.yaml, nothing for the primary config and ``_global_`` files)."""
    text = path.read_text()
    if "# @package _global_" in text:
        prefix = ""
    found: dict[str, str] = {}
    stack: list[tuple[int, str]] = []
    last, column = None, -1  # the key whose comment a comment-only line at the same column continues
    for line in text.splitlines():
        if line.lstrip().startswith("#") and last is not None and line.index("#") == column:
            found[last] += " " + line.strip().lstrip("#").strip()
            continue
        last = None
        match = _LINE.match(line)
        if not match or line.lstrip().startswith(("#", "-")):
            continue
        indent = len(match["indent"])
        while stack and stack[-1][0] >= indent:
            stack.pop()
        stack.append((indent, match["key"]))
        value, _, comment = match["rest"].partition(" #")
        key = prefix + ".".join(k for _, k in stack)
        if comment.strip() and key not in found:
            found[key], last, column = comment.strip(), key, line.index(" #") + 1
    return found


def _config_files(choices: dict[str, Any]) -> list[tuple[Path, str]]:
    """The files a composition read, primary config first, with the package of each."""
    files = [(CONF_DIR / "config.yaml", "")]
    for group, option in choices.items():
        if option is None or group.startswith("hydra"):
            continue
        path, package = group.split("@")[0], (group.split("@")[1] if "@" in group else group)
        names = [option]
        while (CONF_DIR / path / f"{names[-1]}.yaml").is_file():  # an option may extend another (ppo_lstm: ppo)
            base = re.search(
                r"^defaults:\n\s+-\s+([\w-]+)\s*$", (CONF_DIR / path / f"{names[-1]}.yaml").read_text(), re.M
            )
            if base is None or base[1] in names:
                break
            names.append(base[1])
        files += [(CONF_DIR / path / f"{name}.yaml", f"{package}.") for name in names]
    return [(p, pkg) for p, pkg in files if p.is_file()]


def help_text(overrides: list[str], prog: str = "train.py", description: str = "") -> str:
    """``train.py --help``: the groups and their options, then every key of the config composed from ``overrides``
    (``--help algo=dqn`` shows DQN's keys) with its type, default and the meaning its config file gives it."""
    from hydra import compose
    from hydra.core.global_hydra import GlobalHydra

    loader = GlobalHydra.instance().config_loader()
    compose_checked(list(overrides), values=False)  # a bad override is refused as it would be without --help
    cfg = compose("config", overrides=list(overrides), return_hydra_config=True)
    choices = dict(cfg.hydra.runtime.choices)
    with open_dict(cfg):
        del cfg["hydra"]
    meanings = dict(GROUP_KEYS)
    for path, package in _config_files(choices):
        for key, text in comments(path, package).items():
            meanings.setdefault(key, text)
    lines = [
        f"usage: python scripts/{prog} [key=value ...]        (one run)",
        f"       python scripts/{prog} -m key=a,b ... [key=value ...]   (a sweep: one run per combination)",
        "",
    ]
    if description:
        lines += [*textwrap.wrap(" ".join(description.split()), width=114), ""]
    lines.append("groups (group=option; the config below is composed from the options chosen):")
    for group in sorted(g for g in loader.list_groups("") if g not in NOT_TRAINING):
        options = loader.get_group_options(group)
        lines += textwrap.wrap(
            f"{group}: {', '.join(options)} (now {choices.get(group)})",
            width=114,
            initial_indent="  ",
            subsequent_indent="      ",
            break_on_hyphens=False,
        )
    groups = set(loader.list_groups(""))
    lines += [
        "",
        "keys (key=value, nested keys dotted: eval.every=50000; lists key=[a,b]; values read as YAML; "
        "a key not listed needs ++key=value):",
    ]

    def walk(node: DictConfig, path: str) -> None:
        for key in node.keys():
            full = f"{path}{key}"
            if OmegaConf.is_interpolation(node, key):  # shown as written; its type is that of what it refers to
                value = node._get_node(key)._value()
                try:
                    kind = _kind(full, node[key])
                except Exception:  # noqa: BLE001  (a reference only a running job resolves)
                    kind = "reference"
            else:
                value = node[key]
                if OmegaConf.is_dict(value) and full in groups and not len(value):
                    continue  # a group whose option sets nothing (preset=none)
                if OmegaConf.is_dict(value) and len(value) and full not in FREE_FORM:
                    if full in meanings:  # what the keys below have in common
                        lines.append(f"  {full}.*:")
                        lines.extend(
                            textwrap.wrap(meanings[full], width=114, initial_indent=" " * 6, subsequent_indent=" " * 6)
                        )
                    walk(value, f"{full}.")
                    continue
                kind = _kind(full, value)
            lines.append(f"  {full}: {kind} = {show(value)}")
            if full in meanings:
                lines.extend(
                    textwrap.wrap(meanings[full], width=114, initial_indent=" " * 6, subsequent_indent=" " * 6)
                )

    walk(cfg, "")
    lines += [
        "",
        "Hydra's own flags: --cfg job (print the composed config), --hydra-help, -m/--multirun. See docs/training.md.",
    ]
    return "\n".join(lines)


def _kind(full: str, value: Any) -> str:
    """A key's type as --help names it."""
    if value is None:
        kinds = NULLABLE.get(full)
        if kinds is None:
            return "any"
        kinds = tuple(t for t in kinds if not (t is int and float in kinds))  # an int is a float here
        return " or ".join({dict: "mapping"}.get(t, t.__name__) for t in kinds) + " or null"
    if OmegaConf.is_list(value):
        return "list"
    if OmegaConf.is_dict(value):
        return "mapping"
    return type(value).__name__
