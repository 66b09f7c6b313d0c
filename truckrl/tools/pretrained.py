"""``truckrl tools pretrained``: rebuild a task's shipped policy and its model card, from clean code,
with one command (``make pretrained TASK=<task>``).

    truckrl tools pretrained task=intersection
    truckrl tools pretrained task=dock seed=1 out=outputs/dock-seed1/pretrained.pt

From a work tree without uncommitted changes (``allow_dirty=true`` builds from one anyway, and
the card says so), it

1. trains the task's one preset, ``truckrl train experiment=pretrained_<task> seed=S threads=N
   hydra.run.dir=RUN`` (``truckrl/tasks/<task>/conf/experiment/pretrained_<task>.yaml``: a
   frame budget, ``max_minutes`` null, held-out checks by frames, so the result does not depend
   on the machine's speed), in a child process as a user would;
2. scores the run's ``checkpoint`` (last.pt, the final one, by default) with the mean action on
   ``episodes`` held-out scenes of each of ``eval_seeds`` at ``difficulty`` (null: the preset's
   ``curriculum.max_difficulty``, the difficulty it trains at in the end), per scene bin;
3. copies it to ``out`` (default ``truckrl/tasks/<task>/pretrained.pt``) and writes its model card
   beside it (``out`` with the suffix ``.md``) from ``truckrl/tools/card_template.md``: the
   commit, this command, the training command, frames, wall time, machine, threads and the
   held-out table, every figure from this run; the same facts go to ``<RUN>/pretrained.json``.

``train.KEY=VALUE`` changes the training config as ``truckrl train KEY=VALUE`` would (tests use a
tiny frame budget); the card then shows them in both commands. Bad input, a dirty tree and a run
dir that already holds a checkpoint print one line and exit with code 2 before any training.
A stopped build (Ctrl-C, a lost machine) goes on with the same command plus ``run_dir=RUN
resume=true``: ``truckrl train resume=RUN`` continues the run to its frame budget, then the
scoring and the card follow; the card shows both training commands. ``resume=true`` on a run
already at its frame budget trains nothing: it scores the run and writes the card again (into
another ``out=``, say).
"""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

from truckrl.cli import task_folders
from truckrl.config.fields import ConfigError, param, validate
from truckrl.tasks import MAX_DIFFICULTY

PROG = "truckrl tools pretrained"
ABOUT = (
    "Rebuild a task's shipped policy from clean code: train its preset, score it, write its card."
)

TASKS_DIR = Path(__file__).resolve().parent.parent / "tasks"
TEMPLATE = Path(__file__).resolve().parent / "card_template.md"
#: The evaluation scene seeds of the card: ``truckrl eval``'s default and a second set.
EVAL_SEEDS = (12345, 54321)


def preset_path(task: str) -> Path:
    """``truckrl/tasks/<task>/conf/experiment/pretrained_<task>.yaml``."""
    return TASKS_DIR / task / "conf" / "experiment" / f"pretrained_{task}.yaml"


#: Tasks whose folder holds a ``pretrained_<task>`` preset.
TASKS = tuple(t for t in task_folders() if preset_path(t).is_file())


@dataclass
class PretrainedConfig:
    """Which task, which seed, where the policy and its card go."""

    task: str | None = param(None, choices=TASKS, doc="task whose shipped policy to rebuild")
    seed: int = param(0, lo=0, hi=2**62, doc="training seed")
    out: str | None = param(
        None, doc="policy file to write, its card beside it (.md); null: the shipped file"
    )
    run_dir: str | None = param(
        None, doc="training run dir; null: outputs/pretrained/<task>/<date>/<time>"
    )
    checkpoint: str = param("last", choices=("last", "best"), doc="which checkpoint ships")
    difficulty: float | None = param(
        None,
        lo=0.0,
        hi=MAX_DIFFICULTY,
        doc="held-out difficulty; null: the preset's max_difficulty",
    )
    episodes: int = param(1000, lo=1, hi=1_000_000, doc="held-out scenes per scene seed")
    eval_seeds: tuple[int, ...] = param(EVAL_SEEDS, lo=0, hi=2**62, doc="held-out scene seeds")
    threads: int | None = param(
        None,
        lo=1,
        hi=1024,
        doc="torch CPU threads of training and evaluation; null: torch's "
        "default here, passed on as train's threads=N",
    )
    allow_dirty: bool = param(
        False, doc="build from a work tree with uncommitted changes (the card says dirty)"
    )
    resume: bool = param(
        False,
        doc="continue the stopped training in run_dir (same task, seed and frame budget) to "
        "its budget, then score it and write the card",
    )
    train: dict[str, Any] = param(
        {}, doc="training config overrides, as for truckrl train (train.total_frames=4096)"
    )

    def __post_init__(self) -> None:
        if isinstance(self.eval_seeds, int):  # one value for a list of one
            self.eval_seeds = (self.eval_seeds,)
        validate(self)
        if not self.task:
            raise ConfigError(f"task is required: task={'|'.join(TASKS)}")
        if "threads" in self.train:
            raise ConfigError("train.threads: give threads=N, which this command passes on")
        if self.out is not None and not self.out.endswith(".pt"):
            raise ConfigError(f"out = {self.out!r}: a .pt file to write")
        if self.resume and not self.run_dir:
            raise ConfigError("resume=true continues a run: give its run_dir=RUN")


def check_clean(allow_dirty: bool) -> dict:
    """The source's git revision (:func:`truckrl.cli.git_revision`), or a one-line refusal of a
    tree with uncommitted changes, or of a copy outside git, unless ``allow_dirty``."""
    from truckrl import cli

    source = cli.git_revision()
    if allow_dirty:
        return source
    if not source:
        raise ConfigError(
            "the source is not a git checkout, so no commit can name the code that made the "
            "policy: run from a clone, or allow_dirty=true (the card then says so)"
        )
    if source["dirty"]:
        raise ConfigError(
            "the work tree has uncommitted changes (git status): commit or stash them so the card "
            "names the code that made the policy, or allow_dirty=true (the card then says dirty)"
        )
    return source


def check_resumable(last: Path, tc: Any, seed: int) -> None:
    """Refuse in one line a ``resume=true`` whose run dir holds no checkpoint, or a run of
    another task, seed or frame budget than this command would train (``tc``: its config)."""
    if not last.is_file():
        raise ConfigError(f"resume=true: {last} does not exist (run_dir holds no stopped run)")
    import yaml

    from truckrl.rl.checkpoint import load_checkpoint

    saved = yaml.safe_load(load_checkpoint(last)["config"])
    mine = {"task": tc.env.task.name, "seed": seed, "total_frames": tc.total_frames}
    theirs = {"task": saved["env"]["task"]["name"], "seed": saved["seed"],
              "total_frames": saved["total_frames"]}  # fmt: skip
    for key, value in mine.items():
        if theirs[key] != value:
            raise ConfigError(
                f"resume=true: the run in {last.parent.parent} has {key} = {theirs[key]!r}, "
                f"this command {value!r}"
            )


def _quote(value: str) -> str:
    """``value`` as a Hydra override value (quoted when it holds grammar characters)."""
    if all(ch.isalnum() or ch in "/._-+@~:" for ch in value):
        return value
    return "'" + value.replace("\\", "\\\\").replace("'", "\\'") + "'"


def _writable_dir(path: Path, name: str) -> None:
    """Make ``path`` (a folder) or fail in one line naming ``name``."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        if not os.access(path, os.W_OK):
            raise PermissionError(13, "not writable")
    except OSError as e:
        raise ConfigError(
            f"{name} = {str(path)!r}: cannot write there ({e.strerror or e})"
        ) from None


def train_command(head: list[str], threads: int, run_dir: Path) -> list[str]:
    """``truckrl train experiment=pretrained_<task> seed=S OVERRIDE... threads=N
    hydra.run.dir=RUN`` from ``head`` (the experiment, the seed and the overrides)."""
    return [
        "truckrl",
        "train",
        *head,
        f"threads={threads}",
        f"hydra.run.dir={_quote(str(run_dir))}",
    ]


def table(heldouts: dict[int, dict]) -> str:
    """Markdown: one row for all scenes and one per bin, one column per scene seed, cells
    ``success % (scenes)``."""
    seeds = list(heldouts)
    names = list(dict.fromkeys(b for h in heldouts.values() for b in h["bins"]))
    head = "| scenes | " + " | ".join(f"seed {s}: success (scenes)" for s in seeds) + " |"
    lines = [head, "|---|" + "---:|" * len(seeds)]

    def cell(success: float | None, count: int | None) -> str:
        return "-" if success is None else f"{100.0 * success:.1f} % ({count:,})"

    lines.append(
        "| **all** | "
        + " | ".join(f"**{cell(heldouts[s]['success'], heldouts[s]['episodes'])}**" for s in seeds)
        + " |"
    )
    for b in names:
        rows = [heldouts[s]["bins"].get(b) or {"success": None, "count": 0} for s in seeds]
        if all(r["success"] is None for r in rows):
            continue  # no scene of any seed in this bin
        cells = [cell(r["success"], r["count"]) for r in rows]
        lines.append(f"| {b} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def train_child(command: list[str]) -> int:
    """Run ``command`` (``truckrl train ...``) as ``python -m truckrl ...``; its exit code. A
    Ctrl-C reaches the child (the terminal signals the process group), which stops at its next
    iteration boundary with a checkpoint: this process waits for it instead of killing it."""
    import signal
    import threading

    child = subprocess.Popen([sys.executable, "-m", "truckrl", *command[1:]])
    if threading.current_thread() is not threading.main_thread():
        return child.wait()
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        return child.wait()
    finally:
        signal.signal(signal.SIGINT, previous)


def template_parts(text: str) -> tuple[str, dict[str, tuple[str, str]]]:
    """Split the card template into the card and ``{task: (about, more)}`` (module doc of the
    template: a leading comment, the card, then ``<!-- task: NAME -->`` sections)."""
    import re

    body = re.sub(r"\A<!--.*?-->\n", "", text, flags=re.S)
    parts = re.split(r"^<!-- task: (\w+) -->\n", body, flags=re.M)
    card, sections = parts[0], {}
    for name, section in zip(parts[1::2], parts[2::2], strict=True):
        about, _, more = section.strip().partition("\n\n")
        sections[name] = (about.strip(), more.strip())
    return card, sections


def write_card(path: Path, facts: dict) -> str:
    """Fill :data:`TEMPLATE` with ``facts`` (:func:`run`) and write it to ``path``; returns it.

    Raises:
        ConfigError: the template has no section for the task.
    """
    from string import Template

    from truckrl.tasks.config import DEFAULT_TASK

    card, sections = template_parts(TEMPLATE.read_text())
    task = facts["task"]
    if task not in sections:
        raise ConfigError(f"task = {task!r}: {TEMPLATE} has no '<!-- task: {task} -->' section")
    about, more = sections[task]
    source = facts["source"]
    dirty = source.get("dirty", True)
    text = Template(card).substitute(
        task=task,
        file=path.with_suffix(".pt").name,
        about=about,
        more=f"\n{more}\n" if more else "",
        default_note=" (or `checkpoint=pretrained`: the default task)"
        if task == DEFAULT_TASK
        else "",
        commit=facts["commit"],
        clean="uncommitted changes in the work tree: built with allow_dirty=true"
        if dirty
        else "a clean work tree",
        command=facts["command"].replace(
            f"run_dir={_quote(facts.get('run_dir') or 'RUN')}", "run_dir=RUN"
        ),
        runs=" in one run, stopped once and continued by the same command with `resume=true`"
        if facts.get("resumed")
        else " in one run",
        # the run dir is the building machine's path: the card names it RUN (the JSON keeps it)
        train_command=facts["train_command"].replace(_quote(facts.get("run_dir") or "RUN"), "RUN"),
        frames=f"{facts['frames']:,}",
        minutes=f"{facts['wall_time_s'] / 60.0:.1f}",
        machine=facts["machine"],
        threads=facts["threads"],
        which=facts["checkpoint"],
        features=facts["num_obs"],
        beams=facts["num_beams"],
        final_difficulty=f"{facts['final_difficulty']:g}",
        episodes=f"{facts['episodes']:,}",
        difficulty=f"{facts['difficulty']:g}",
        tolerance=f"{facts['tolerance'][0]:.3g} m and {facts['tolerance'][1]:.3g} deg",
        table=table({int(s): h for s, h in facts["heldout"].items()}),
        eval_commands="\n".join(facts["eval_commands"]),
    )
    path.write_text(text)
    return text


def _copy(src: Path, dst: Path) -> None:
    """Copy ``src`` to ``dst`` atomically (a temporary file beside ``dst``, renamed)."""
    import shutil
    import tempfile

    fd, tmp = tempfile.mkstemp(dir=dst.parent, prefix=f".{dst.name}.", suffix=".tmp")
    os.close(fd)
    try:
        shutil.copyfile(src, tmp)
        os.replace(tmp, dst)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def run(cfg: PretrainedConfig, argv: list[str], overrides: list[str]) -> dict:
    """Check, train, score, copy and write the card (module doc); returns the card's facts.

    ``argv``: this command's arguments as given; ``overrides``: the ``train.`` ones without the
    prefix, as written (Hydra parses them).
    """
    source = check_clean(cfg.allow_dirty)
    task = cfg.task

    from truckrl.cli import compose_config
    from truckrl.config.schemas import TrainConfig
    from truckrl.rl.checkpoint import BEST_NAME, CHECKPOINT_DIR, LAST_NAME, load_training_state

    head = [f"experiment=pretrained_{task}", f"seed={cfg.seed}", *overrides]
    tc = compose_config("train", TrainConfig, head)  # a bad override: one line, before training
    difficulty = tc.curriculum.max_difficulty if cfg.difficulty is None else cfg.difficulty
    stamp = datetime.now().strftime("%Y-%m-%d/%H-%M-%S")
    run_dir = Path(cfg.run_dir or f"outputs/pretrained/{task}/{stamp}")
    last = run_dir / CHECKPOINT_DIR / LAST_NAME
    if cfg.resume:
        check_resumable(last, tc, cfg.seed)
    elif last.exists():
        raise ConfigError(
            f"run_dir = {str(run_dir)!r} already holds a checkpoint: name another, or "
            "resume=true to continue it"
        )
    out = Path(cfg.out) if cfg.out else TASKS_DIR / task / "pretrained.pt"
    _writable_dir(out.parent, "out")
    _writable_dir(run_dir.parent, "run_dir")

    import torch

    threads = cfg.threads or torch.get_num_threads()
    command = shlex.join(["truckrl", "tools", "pretrained", *argv])
    # the card names the build command; a resume is that command plus resume=true
    build = shlex.join(["truckrl", "tools", "pretrained", *(a for a in argv if a != "resume=true")])
    ran = [train_command(head, threads, run_dir)]
    # the run's own config and frame budget, whatever time the stop was about
    resume = ["truckrl", "train", f"resume={_quote(str(run_dir))}", f"threads={threads}",
              "max_minutes=null"]  # fmt: skip
    todo: list[str] | None = ran[0]  # the command this call trains with (None: nothing left)
    resumed = False
    if cfg.resume:
        before = load_training_state(last)["counters"]["frames"]
        if tc.total_frames is None or before < tc.total_frames:
            todo, resumed = resume, True
        else:  # a finished run scored again: what its earlier scoring recorded stands
            todo, earlier = None, run_dir / "pretrained.json"
            resumed = earlier.is_file() and bool(json.loads(earlier.read_text()).get("resumed"))
        ran += [resume] if resumed else []
    if todo is None:
        print(f"{command}\n{run_dir} is at its frame budget ({before:,} frames): scoring it",
              flush=True)  # fmt: skip
        code = 0
    else:
        print(f"{command}\ntraining: {shlex.join(todo)}", flush=True)
        code = train_child(todo)
    ckpt = run_dir / CHECKPOINT_DIR / (BEST_NAME if cfg.checkpoint == "best" else LAST_NAME)
    if code != 0 or not ckpt.is_file():
        raise ConfigError(
            f"training stopped with exit code {code} without {ckpt}: see its output above "
            f"and {run_dir / 'train.log'}; nothing was copied"
        )
    done = load_training_state(run_dir / CHECKPOINT_DIR / LAST_NAME)["counters"]["frames"]
    if tc.total_frames is not None and done < tc.total_frames:
        raise ConfigError(
            f"training stopped at {done:,} of total_frames = {tc.total_frames:,} frames (a "
            f"signal?): nothing was copied; the same command with run_dir={run_dir} "
            "resume=true continues it"
        )

    from truckrl.tools.stats import commit_of, heldout_by_bin, machine

    torch.set_num_threads(threads)
    heldout = {}
    for seed in cfg.eval_seeds:
        print(f"held-out: {ckpt} on {cfg.episodes} scenes of seed {seed} at difficulty "
              f"{difficulty:g}", flush=True)  # fmt: skip
        heldout[seed] = heldout_by_bin(str(ckpt), difficulty, cfg.episodes, seed)
    state = load_training_state(ckpt)
    recorded = dict(state.get("source") or source or {})
    shipped = cfg.out is None or out.resolve() == (TASKS_DIR / task / "pretrained.pt").resolve()
    spec = f"pretrained:{task}" if shipped else str(out)
    facts = {
        "task": task,
        "source": recorded,
        "commit": commit_of(recorded) or "unknown (not a git checkout)",
        "command": build,
        "resumed": bool(resumed),
        "train_command": "\n".join(shlex.join(c) for c in ran),
        "run_dir": str(run_dir),
        "checkpoint": cfg.checkpoint,
        "frames": int(state["counters"]["frames"]),
        "wall_time_s": float(state["counters"]["wall_time_s"]),
        "machine": machine(),
        "threads": threads,
        "num_obs": int(state["num_obs"]),
        "num_beams": int(state["num_beams"]),
        "final_difficulty": float(state["curriculum"]["difficulty"]),
        "difficulty": float(difficulty),
        "tolerance": heldout[cfg.eval_seeds[0]]["tolerance"],
        "episodes": cfg.episodes,
        "heldout": {str(s): h for s, h in heldout.items()},
        "eval_commands": [
            shlex.join(
                [
                    "truckrl",
                    "eval",
                    f"checkpoint={spec}",
                    f"difficulty={difficulty:g}",
                    f"episodes={cfg.episodes}",
                    f"seed={s}",
                ]
            )  # fmt: skip
            for s in cfg.eval_seeds
        ],
    }
    _copy(ckpt, out)
    card = out.with_suffix(".md")
    text = write_card(card, facts)
    (run_dir / "pretrained.json").write_text(json.dumps(facts, indent=2) + "\n")
    print(f"\n{text.split('## How well it drives', 1)[1].strip()}\n")
    print(f"wrote {out} and {card} ({run_dir / 'pretrained.json'})")
    return facts


def main(argv: list[str] | None = None) -> int:
    from truckrl.cli import key_value_config, run_or_fail

    argv = sys.argv[1:] if argv is None else list(argv)
    cfg = key_value_config(PretrainedConfig, argv, PROG, ABOUT)
    # the train overrides as written (Hydra parses them; YAML would reformat their values)
    overrides = [a.removeprefix("train.") for a in argv if a.startswith("train.")]
    return run_or_fail(lambda c: run(c, argv, overrides), cfg)


if __name__ == "__main__":
    sys.exit(main())
