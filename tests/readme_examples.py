"""README.md's examples and where each is exercised (tests/test_readme_examples.py checks both ways).

:func:`readme_examples` extracts every shell command (each line of a ```` ```bash ```` block, its comment dropped, and
every inline ``python -m …``, ``make …``, ``dvc …`` and ``pip install …`` span of the prose and tables) and every
```` ```yaml ```` block. :data:`REGISTRY` maps each to the test that runs it, by a pattern on the command's words
joined by single spaces (:attr:`Example.text`); an entry whose ``test`` is ``None`` is an exemption, its ``note`` the
reason and where its shape is tested.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"
FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M)
INLINE = re.compile(r"`([^`]+)`")
COMMAND_START = re.compile(r"(python -m |make |dvc |pip install )")


@dataclass(frozen=True)
class Example:
    """One README example: ``kind`` is ``bash`` (a line of a bash block), ``inline`` (a code span) or ``yaml`` (a
    whole block, ``text`` its body); ``line`` is its 1-based line in the README."""

    kind: str
    text: str
    line: int

    @property
    def argv(self) -> list[str]:
        return self.text.split(" ")


def _words(command: str) -> str:
    """A command's words (shell quoting and a trailing comment removed) joined by single spaces."""
    return " ".join(shlex.split(command, comments=True))


def readme_examples(text: str) -> list[Example]:
    """Every shell command and YAML block of the Markdown ``text`` (see the module docstring)."""
    out: list[Example] = []
    prose = text
    for block in FENCE.finditer(text):
        lang, body = block.group(1), block.group(2)
        first = text.count("\n", 0, block.start(2)) + 1
        if lang == "yaml":
            out.append(Example("yaml", body, first))
        elif lang in ("bash", "sh", "shell", "console"):
            for i, line in enumerate(body.splitlines()):
                if words := _words(line):
                    out.append(Example("bash", words, first + i))
        prose = prose[:block.start()] + re.sub(r"[^\n]", " ", block.group(0)) + prose[block.end():]  # keep offsets
    for span in INLINE.finditer(prose):
        code = " ".join(span.group(1).split())
        if COMMAND_START.match(code):
            out.append(Example("inline", _words(code), prose.count("\n", 0, span.start()) + 1))
    return sorted(out, key=lambda e: e.line)


@dataclass(frozen=True)
class Entry:
    """``pattern`` (a regular expression matched against the whole of :attr:`Example.text`; ``kind`` yaml entries
    match any YAML block) → ``test`` (``path::function`` that runs it) or ``None`` for an exemption; ``note`` says how
    the test uses the example, or why it is exempt and which tests cover its shape."""

    pattern: str
    test: str | None
    note: str
    kind: str = "command"

    def matches(self, example: Example) -> bool:
        if self.kind == "yaml" or example.kind == "yaml":
            return self.kind == example.kind == "yaml"
        return re.fullmatch(self.pattern, example.text) is not None


HERE = "tests/test_readme_examples.py"
WORKFLOW = "tests/test_readme_workflow.py::test_readme_workflow_takes_a_bare_splat_and_a_painting_to_a_stylized_splat"
E2E = "tests/test_pipeline_e2e.py"
ADD_SCENE = [
    "python -m abcgs add-scene garden /data/garden",
    "python -m abcgs add-scene bonsai /data/360_v2/bonsai --images images_4",
    "python -m abcgs add-scene fern /data/nerf_llff_data/fern --format llff --images images_8",
    "python -m abcgs add-scene poster /data/nerfstudio/poster",
    "python -m abcgs add-scene lego /data/nerf_synthetic/lego --background 1 1 1",
    "python -m abcgs add-scene garden /data/garden --splat /data/gs_out/garden",
    "python -m abcgs add-scene chair /data/chair.splat",
]
ADD_STYLE = [
    "python -m abcgs add-style starry /data/starry.jpg",
    "python -m abcgs add-style starry /data/starry.jpg --labels /data/starry_labels.png",
    "python -m abcgs add-style starry /data/paintings/starry.jpg --labels /data/paintings/starry_labels.png",
]
ADD_EXPERIMENT = [
    "python -m abcgs add-experiment garden_starry --scene garden --style starry --method fast nnfm",
    "python -m abcgs add-experiment garden_semantic --scene garden --style starry --binding 1=3 2=2 3=1",
]

REGISTRY: list[Entry] = [
    *(Entry(re.escape(c), f"{HERE}::test_add_scene_example_runs_as_written",
            "run as written on a generated folder of the README path's shape") for c in ADD_SCENE),
    *(Entry(re.escape(c), f"{HERE}::test_add_style_example_runs_as_written",
            "run as written on a generated painting (and region map)") for c in ADD_STYLE),
    *(Entry(re.escape(c), f"{HERE}::test_add_experiment_example_runs_as_written",
            "run as written after the README's add-scene and add-style of its scene and painting") for c in
      ADD_EXPERIMENT),
    Entry("", f"{HERE}::test_yaml_block_validates_and_passes_preflight", "merged into a params copy, validated, "
          "preflight-checked; its fit override is fitted on the tiny scene by test_yaml_fit_override_fits_the_tiny_"
          "scene", kind="yaml"),
    Entry(r"python -m abcgs add-scene NAME PATH", f"{HERE}::test_add_scene_example_runs_as_written",
          "the synopsis of the table's rows, each run as written"),
    Entry(r"make repro( ARGS=(…|\.\.\.))?", WORKFLOW, "the command add-experiment prints, run as printed (its "
          "recipe's steps, read from the Makefile: the copy has no .venv for make to reuse)"),
    Entry(r"python -m abcgs\.preflight params\.yaml", WORKFLOW, "the second step of make repro's recipe, as written"),
    Entry(r"python -m abcgs\.view out/(garden_starry|<experiment>)", WORKFLOW,
          "run with --no-open on the workflow's experiment"),
    Entry(r"python -m abcgs\.dag --write", "tests/test_dag.py::test_dvc_yaml_is_what_the_stage_specs_make",
          "dvc.yaml equals what the generator writes"),
    Entry(r"pip install -e \.\[cuda\]", f"{HERE}::test_pip_extras_named_by_the_readme_exist",
          "the installed package declares the extra and its requirement; installing it needs the network and a GPU"),
    Entry(r"python -m abcgs\.masks\.page /data/garden",
          "tests/test_paint_browser.py::test_strokes_on_a_view_segment_and_save_a_mask",
          "the page on a folder of photos, driven in chromium"),
    Entry(r"python -m abcgs\.masks\.page --painting /data/paintings/starry\.jpg",
          "tests/test_paint_browser.py::test_the_painting_mode_writes_its_label_map",
          "the painting mode writes <painting>_labels.png"),
    Entry(r"python -m abcgs\.cluster submit --cluster-dir /shared/\$USER/abcgs",
          "tests/test_cluster.py::test_every_job_completes_and_the_killed_one_was_retried", "on a local Slurm stand-in"),
    Entry(r"python -m abcgs\.cluster status", "tests/test_cluster.py::test_status_showed_the_killed_stage_and_its_log",
          "on a local Slurm stand-in"),
    Entry(r"python -m abcgs\.cluster collect", "tests/test_cluster.py::test_collect_restores_every_stage_and_runs_none",
          "on a local Slurm stand-in"),
    Entry(r"dvc metrics show", f"{E2E}::test_dvc_metrics_show_is_a_short_headline_table", "on the tiny pipeline"),
    Entry(r"dvc plots show", f"{E2E}::test_dvc_plots_show_writes_the_loss_curves", "on the tiny pipeline"),
    Entry(r"dvc params diff", f"{E2E}::test_a_scene_override_reruns_only_that_scenes_branch", "on the tiny pipeline"),
    Entry(r"dvc exp run( -S key=value)?", f"{E2E}::test_a_queued_sweep_runs_two_experiments_at_once",
          "dvc exp run -S on the tiny pipeline (queued)"),
    Entry(r"dvc repro( -s)?", "tests/test_stage_commands.py::test_a_hostile_experiment_name_runs_no_command",
          "dvc repro -s and --downstream on a copy; plain dvc repro: every tests/test_pipeline_*.py"),
    Entry(r"make (run|test|install)", None, "what CI itself runs (make install is the first step of both; make test runs this file; make run is "
          "dvc repro of the "
          "tiny pipeline after the same preflight, as tests/test_pipeline_e2e.py runs it)"),
    Entry(r"make quality", None, "needs ../shared/data (fern); its shape, a benchmark overlay run as a DVC "
          "experiment, is tests/test_bench_experiment.py::test_the_experiment_starts_with_the_dvc_yaml_of_its_overlay"),
    Entry(r"make viewer", None, "needs npm and the network; the committed bundle it builds is driven by "
          "tests/test_viewer_browser.py"),
    Entry(r"python -m eval run first_run", None, "times a fresh install and make run on a new machine (minutes, "
          "the network); its steps are make run's"),
    Entry(r"python -m eval list", "tests/test_eval_suite.py::test_list_prints_one_line_per_benchmark",
          "run as written; one line per benchmark of the suite"),
    Entry(r"python -m eval run test_suite",
          "tests/test_eval_suite.py::test_the_test_suite_benchmark_times_a_pytest_run_and_keeps_its_outcomes",
          "run on a small test file of its own (the whole suite is what CI runs)"),
    Entry(r"python -m eval records --status", "tests/test_records.py::test_status_names_each_record_once",
          "run with --root on a copy of docs/'s DVC project over the tree's files, and as written where no run of "
          "the records pipeline holds docs/"),
    Entry(r"python -m eval run <name>",
          "tests/test_eval_suite.py::test_run_passes_the_arguments_after_the_name_to_the_benchmark",
          "run with a benchmark's name and its own --help"),
]


def exercisers(example: Example) -> list[Entry]:
    """The registry entries that match ``example``."""
    return [e for e in REGISTRY if e.matches(example)]
