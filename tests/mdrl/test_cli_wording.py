"""What `drlaas train` and `drlaas eval` say when a user gets something wrong (a user audit):
one line naming what is wrong and what to give instead, no traceback. The CLI is invoked as in
test_cli_robustness.py, whose helpers these tests reuse."""

import json
import re
import shutil

import pytest
import typer
from typer.testing import CliRunner

from tests.mdrl.test_cli_robustness import (
    QUIET,
    assert_clean_exit,
    assert_usage_error,
    flat,
    invoke,
    make_app,
)
from workers.mdrl.presets import PRESETS


# ---------------------------------------------------------------- 1. nothing left to train
@pytest.mark.parametrize(("budget", "named"), [
    (["--steps", 64], "the run already has 64 steps, its budget is 64; give a larger --steps"),
    (["--minutes", 1e-6], "give a larger --minutes"),
])
def test_resume_with_its_budget_used_up_says_nothing_was_trained(trained, budget, named):
    """A resume whose budget the run already reached exited 0 with the old summary, which
    read as a finished training: it still exits 0 (the run is as asked), saying so on
    stderr."""
    res = invoke("train", "--resume", trained, *budget, *QUIET)
    assert_clean_exit(res, 0)
    assert "nothing to train" in res.stderr and named in res.stderr
    assert json.loads(res.stdout.strip().splitlines()[-1])["env_steps"] == 64


# ---------------------------------------------------------------- 2. a wrong preset
def test_an_unknown_preset_names_the_closest_ones_and_how_to_list_them(tmp_path):
    """The error listed all ~190 presets (50 lines) and no suggestion."""
    res = invoke("train", "--preset", "odmtl-3a-10x1", "--steps", 64, "--out", tmp_path / "r",
                 *QUIET)
    assert_usage_error(res, "--preset", "unknown preset 'odmtl-3a-10x1'",
                       "did you mean odmtl-3a-10x10", "--list-presets")
    assert "ch4-a4w3-sparse-t41" not in flat(res)  # not the whole list
    res = invoke("train", "--preset", "zzz", "--steps", 64, "--out", tmp_path / "r", *QUIET)
    assert_usage_error(res, "unknown preset 'zzz'", "the families are", "--list-presets")


def test_list_presets_prints_every_preset_and_the_help_points_to_it():
    """The help pointed to a source file (cut off as `workers/mdrl/presets.p…`)."""
    res = invoke("train", "--list-presets")
    assert_clean_exit(res, 0)
    assert [line.split()[0] for line in res.stdout.splitlines()] == list(PRESETS)
    res = invoke("train", "--help")
    assert "--list-presets lists them" in flat(res) and "presets.py" not in res.output


# ---------------------------------------------------------------- 3. a config that does not parse
@pytest.mark.parametrize(("name", "text", "named"), [
    ("bad.json", '{"env": {"rows": }}', "not valid JSON (line 1, column 18: Expecting value)"),
    ("empty.json", "", "not valid JSON (line 1, column 1"),
    ("bad.toml", "[env]\nrows = \n", "not valid TOML (Invalid value"),
])
def test_a_config_that_does_not_parse_names_the_file_and_its_format(tmp_path, monkeypatch,
                                                                     name, text, named):
    """The parser's message alone (`Expecting value: line 1 column 1 (char 0)`) named neither
    the file nor JSON."""
    monkeypatch.chdir(tmp_path)  # a short relative path: the message is not wrapped inside it
    (tmp_path / name).write_text(text)
    res = invoke("train", "--config", name, "--steps", 64, "--out", "r", *QUIET)
    assert_usage_error(res, "--config", f"{name}: {named}")


# ---------------------------------------------------------------- 4. --resume of nothing
def test_resume_of_a_missing_directory_names_it_before_the_budget(tmp_path):
    """Without a budget, `--resume /missing` complained about the budget."""
    res = invoke("train", "--resume", tmp_path / "missing", *QUIET)
    assert_usage_error(res, "--resume", "no such directory")
    assert "budget" not in flat(res)
    res = invoke("train", "--resume", tmp_path, *QUIET)  # a directory without a checkpoint
    assert_usage_error(res, "--resume", "not a checkpoint directory")
    assert "budget" not in flat(res)


# ---------------------------------------------------------------- 5. eval of a run directory
def test_eval_of_a_run_directory_names_its_models(trained, monkeypatch):
    """`--policy RUN` (a `drlaas train --out`) said only `no model.json`; model/ and best/
    are different policies, so the error names them rather than picking one."""
    run = trained  # a directory named run/
    monkeypatch.chdir(run.parent)
    res = invoke("eval", "--policy", "run", "--episodes", 2)
    assert_usage_error(res, "--policy", "training run directory", "--policy run/model")
    assert "run/best" not in flat(res)
    shutil.copytree(run / "model", run / "best")
    try:
        res = invoke("eval", "--policy", "run", "--episodes", 2)
        assert_usage_error(res, "--policy run/model or --policy run/best")
    finally:
        shutil.rmtree(run / "best")


# ---------------------------------------------------------------- 6. help texts
@pytest.mark.parametrize("command", ["train", "eval"])
def test_help_texts_are_not_cut_off_at_80_columns(command):
    """Rich cuts a word too long for its column (`--steps/--minutes/--se…`)."""
    res = CliRunner().invoke(make_app(), [command, "--help"], env={"COLUMNS": "80"})
    assert_clean_exit(res, 0)
    assert "…" not in res.output, [line for line in res.output.splitlines() if "…" in line]


SOURCE_MARKUP = re.compile(r"``|:[a-z]+:`|\.\. [a-z-]+::")
"""reStructuredText / Sphinx markup of docstrings (``literal``, :func:`name`, .. note::): typer
prints a command's docstring as its help, where the markup reaches the user as it is."""


def command_paths(cmd, path=()):
    """Every command of a click group, as argv prefixes (the group itself first)."""
    yield list(path)
    for name, sub in sorted(getattr(cmd, "commands", {}).items()):
        yield from command_paths(sub, [*path, name])


def test_no_option_name_is_cut_off_at_80_columns():
    """A `--flag/--no-flag` pair widened the names column of `drlaas task submit --help` until
    Rich cut `--public-outcome` to `--public-outco…` and squeezed every help text to a few
    words a line."""
    from drlaas.cli import app

    runner, cut = CliRunner(), []
    for path in command_paths(typer.main.get_command(app)):
        res = runner.invoke(app, [*path, "--help"], env={"COLUMNS": "80"})
        assert_clean_exit(res, 0)
        cut += [f"drlaas {' '.join(path)}: {line.strip()}"
                for line in res.output.splitlines() if re.search(r"--[\w-]*…", line)]
    assert not cut, "\n".join(cut)


def test_no_help_text_shows_docstring_markup():
    """Every `drlaas` command's --help (the platform's and the core's) is plain text: `drlaas
    model push --help` showed ``experts`` (user audit)."""
    from drlaas.cli import app

    runner, marked = CliRunner(), []
    for path in command_paths(typer.main.get_command(app)):
        res = runner.invoke(app, [*path, "--help"], env={"COLUMNS": "200"})
        assert_clean_exit(res, 0)
        marked += [f"drlaas {' '.join(path)}: {line.strip()}"
                   for line in res.output.splitlines() if SOURCE_MARKUP.search(line)]
    assert not marked, "\n".join(marked)
