"""The documentation's links lead somewhere, and the READMEs stay short.

Every relative link in every Markdown file of the repository (`[text](path)`,
`[text](path#anchor)`, images too) must name a file or directory that exists, and an
anchor into a Markdown file must name one of its headings: a moved or renamed file or
section otherwise leaves a dead link that nobody notices. Links to web pages and bare
`#anchor` links into the same file are not checked. The README and each package's
README are for a newcomer and stay within 300 lines; longer material lives in
`<package>/doc/`.
"""

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
MAX_README_LINES = 300
READMES = ["README.md", "gravgrasp_detector/README.md", "sim_bridge/README.md",
           "robotiq_driver/README.md", "gravgrasp_msgs/README.md"]

LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
FENCE = re.compile(r"^(```|~~~)")
CODE_SPAN = re.compile(r"`[^`]*`")
HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")


def markdown_files() -> list:
    """Tracked Markdown files, and new ones git does not ignore (out/ is ignored)."""
    out = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "*.md"],
                         cwd=ROOT, check=True, capture_output=True, text=True).stdout.split("\n")
    return sorted(p for p in set(out) if p and not p.startswith("out/") and (ROOT / p).is_file())


def prose_lines(text: str):
    """(line number, line) outside fenced code blocks, with inline code spans removed."""
    fenced = False
    for n, line in enumerate(text.split("\n"), 1):
        if FENCE.match(line.lstrip()):
            fenced = not fenced
            continue
        if not fenced:
            yield n, CODE_SPAN.sub("", line)


def github_anchor(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link in a heading: its text
    text = re.sub(r"[^\w\- ]", "", text.replace("`", "").lower())
    return text.replace(" ", "-")


def anchors(path: Path) -> set:
    seen, out = {}, set()
    fenced = False
    for line in path.read_text().split("\n"):
        if FENCE.match(line.lstrip()):
            fenced = not fenced
            continue
        m = None if fenced else HEADING.match(line)
        if m:
            a = github_anchor(m.group(2))
            out.add(a if a not in seen else f"{a}-{seen[a]}")
            seen[a] = seen.get(a, 0) + 1
    return out


def broken_links(md: str) -> list:
    path = ROOT / md
    problems = []
    for n, line in prose_lines(path.read_text()):
        for target in LINK.findall(line):
            if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I) or target.startswith("#"):
                continue  # a web page, mailto:, or an anchor in this file
            rel, _, anchor = target.partition("#")
            dest = (path.parent / rel).resolve()
            if not dest.exists():
                problems.append(f"{md}:{n}: {target} (no such file or directory)")
            elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
                problems.append(f"{md}:{n}: {target} (no heading '#{anchor}' in {rel})")
    return problems


def test_github_anchor_follows_github_rules():
    assert github_anchor("Soak: does it hold up for hours? (`make soak`)") == \
        "soak-does-it-hold-up-for-hours-make-soak"
    assert github_anchor("`ros2 run gravgrasp_detector ur_arm` — a UR arm") == \
        "ros2-run-gravgrasp_detector-ur_arm--a-ur-arm"


def test_the_checker_finds_a_dead_link(tmp_path, monkeypatch):
    (tmp_path / "doc").mkdir()
    (tmp_path / "doc" / "a.md").write_text("# A\n\n## Part two\n")
    (tmp_path / "b.md").write_text("[ok](doc/a.md#part-two) [dir](doc/) [web](https://x.org/y)\n"
                                   "`[code](nowhere.md)`\n[gone](doc/missing.md) [bad](doc/a.md#part-three)\n")
    monkeypatch.setattr(__import__(__name__), "ROOT", tmp_path)
    assert broken_links("b.md") == ["b.md:3: doc/missing.md (no such file or directory)",
                                    "b.md:3: doc/a.md#part-three (no heading '#part-three' in doc/a.md)"]


def test_every_relative_link_in_every_markdown_file_resolves():
    files = markdown_files()
    assert "README.md" in files and len(files) > 10
    problems = [p for md in files for p in broken_links(md)]
    assert not problems, f"{len(problems)} dead links:\n" + "\n".join(problems)


@pytest.mark.parametrize("readme", READMES)
def test_readmes_stay_short(readme):
    n = len((ROOT / readme).read_text().split("\n"))
    assert n <= MAX_README_LINES, f"{readme} has {n} lines (at most {MAX_README_LINES}): move detail to <package>/doc/"


MODULE_COMMAND = re.compile(r"python -m ((?:sim_bridge|gravgrasp_detector|robotiq_driver)(?:\.\w+)*)")


def missing_modules(text: str, where: str) -> list:
    """`python -m <project module>` lines whose module is not in the tree. A line that runs
    an older commit's worktree (`out/pinned/`) names that commit's modules and is skipped."""
    problems = []
    for n, line in enumerate(text.split("\n"), 1):
        if "out/pinned/" in line:
            continue
        for module in MODULE_COMMAND.findall(line):
            top, *rest = module.split(".")
            base = ROOT / top / top / Path(*rest) if rest else ROOT / top / top
            if not (base.with_suffix(".py").is_file() or (base / "__init__.py").is_file()):
                problems.append(f"{where}:{n}: python -m {module} (no such module)")
    return problems


def test_the_checker_finds_a_moved_module():
    assert missing_modules("python -m sim_bridge.analysis.fresh_scenes RUN\npython -m sim_bridge.benchmark.fresh_scenes RUN\n"
                           "python -m sim_bridge.datagen objects\n(out/pinned/a47ba91: python -m sim_bridge.benchmark.replay)",
                           "x.md") == ["x.md:2: python -m sim_bridge.benchmark.fresh_scenes (no such module)"]


def test_every_python_m_command_in_the_docs_and_recipes_names_a_module_that_exists():
    """A command a reader copies from a doc, a recipe or the Makefile must still run: a moved
    module otherwise leaves a command that fails (the docs' links are checked above)."""
    recipes = sorted(str(p.relative_to(ROOT)) for p in (ROOT / "sim_bridge" / "chains").glob("*.sh"))
    problems = [p for f in markdown_files() + recipes + ["Makefile"]
                for p in missing_modules((ROOT / f).read_text(), f)]
    assert not problems, f"{len(problems)} commands name a module that is gone:\n" + "\n".join(problems)


ROS2_RUN = re.compile(r"ros2 run (sim_bridge|gravgrasp_detector|robotiq_driver) (\w+)")


def executables(package: str) -> set:
    """The `ros2 run` executables a package's setup.py installs (its console_scripts)."""
    return set(re.findall(r'"(\w+) = ', (ROOT / package / "setup.py").read_text()))


def unknown_flags(text: str, where: str) -> list:
    """In `python -m <project module>` and `ros2 run <project package> <executable>` commands:
    executables the package does not install, and `--flags` that no source file of the
    command's top package names: a renamed or mistyped option, which a long chain would
    otherwise meet hours in. Read from the source (no import, so it is fast; some commands
    hand their options on to another module, e.g. detection_levers): loose, but a typo or a
    removed option names nothing. A node's `--ros-args` and what follows are ROS's."""
    problems, sources = [], {}
    joined = re.sub(r"\\\n\s*", " ", text)  # one line per command
    for n, line in enumerate(joined.split("\n"), 1):
        if "out/pinned/" in line:
            continue
        commands = [(f"python -m {m.group(1)}", m.group(1).split(".")[0], m.end()) for m in MODULE_COMMAND.finditer(line)]
        for m in ROS2_RUN.finditer(line):
            if m.group(2) not in executables(m.group(1)):
                problems.append(f"{where}: ros2 run {m.group(1)} {m.group(2)} (no such executable)")
            commands.append((f"ros2 run {m.group(1)} {m.group(2)}", m.group(1), m.end()))
        for name, top, end in commands:
            if top not in sources:
                sources[top] = "\n".join(p.read_text() for p in (ROOT / top / top).rglob("*.py"))
            command = re.split(r"\||>|&&|;|--ros-args", line[end:])[0]
            for flag in re.findall(r"(?<![\w-])(--[a-z][a-z0-9-]*)", command):
                if flag != "--help" and f'"{flag}"' not in sources[top] and f"'{flag}'" not in sources[top]:
                    problems.append(f"{where}: {name} {flag} (no such option)")
    return problems


def test_the_flag_checker_finds_a_mistyped_option():
    recipe = ("python -m sim_bridge.datagen.data_report \"$t\" --scenes \"$s\" \\\n  --png x.png > r.txt\n"
              "python -m sim_bridge.studies.rescore_drift T --mesh M | tail\n")
    assert unknown_flags(recipe, "x.sh") == ["x.sh: python -m sim_bridge.studies.rescore_drift --mesh (no such option)"]
    doc = ("ros2 run sim_bridge demo --help; ros2 run sim_bridge benchmark --out R --report\n"
           "ros2 run gravgrasp_detector detect --ros-args -p model_path:=m.pt\n"
           "ros2 run sim_bridge clutter_demo --seed 1\nros2 run sim_bridge datagen scenes --scene-count 3\n")
    assert unknown_flags(doc, "x.md") == ["x.md: ros2 run sim_bridge clutter_demo (no such executable)",
                                          "x.md: ros2 run sim_bridge datagen --scene-count (no such option)"]


def test_every_option_a_chain_a_doc_or_the_makefile_passes_exists():
    """The chains run for hours and resume per step: an option a step's module no longer
    has would stop them at that step, possibly sessions after the start; in a doc or the
    Makefile it is a command that fails for the reader."""
    recipes = sorted(str(p.relative_to(ROOT)) for p in (ROOT / "sim_bridge" / "chains").glob("*.sh"))
    problems = [p for f in recipes + markdown_files() + ["Makefile"]
                for p in unknown_flags((ROOT / f).read_text(), f)]
    assert not problems, "\n".join(problems)


BENCHMARK_COMMAND = re.compile(r"(ros2 run sim_bridge benchmark|python -m sim_bridge\.benchmark\.clutter_benchmark"
                               r"|python -m sim_bridge\.studies\.detection_levers)(?!\w)")
LEVER_TOOLS = re.compile(r"\s+(paired_run|replay|round_profile)\b")  # detection_levers TOOL: not the benchmark


def unknown_methods(text: str, where: str, shipped: set, with_levers: set) -> list:
    """`--methods` of benchmark commands that the command does not know: the benchmark knows
    the shipped methods and the paper's baselines; a lever is a study's method, known to
    `python -m sim_bridge.studies.detection_levers` (the benchmark's options, its methods
    registered). A lever given to `ros2 run sim_bridge benchmark` is "unknown method"."""
    problems = []
    for line in one_line_per_command(text):
        if "out/pinned/" in line or "run_pinned.sh" in line:  # an older commit's methods
            continue
        for m in BENCHMARK_COMMAND.finditer(line):
            command = re.split(r"\||>|&&|;|`", line[m.end():])[0]
            levers = m.group(1).endswith("detection_levers")
            if levers and LEVER_TOOLS.match(command):
                continue
            models = re.findall(r"--model[ =](\S+)", command)  # --model NAME=PATH names a method
            if any("$" in model for model in models):
                continue  # a name the shell fills in
            named = {model.strip("'\"").split("=")[0] for model in models}
            for names in re.findall(r"--methods[ =]([\w,]+)", command):
                for name in names.split(","):
                    if name not in (with_levers if levers else shipped) | named:
                        hint = " (a lever: python -m sim_bridge.studies.detection_levers)" if name in with_levers else ""
                        problems.append(f"{where}: {m.group(1)} --methods {name}: unknown method{hint}")
    return problems


def one_line_per_command(text: str) -> list:
    """The lines of a doc or recipe with each command on one: shell continuations joined,
    and outside fenced blocks, a code span that prose wrapped over lines."""
    text = re.sub(r"\\\n\s*", " ", text)
    parts = re.split(r"(^```.*?^```)", text, flags=re.S | re.M)  # odd parts: fenced blocks
    return "".join(part if i % 2 else re.sub(r"`[^`]*`", lambda m: m.group(0).replace("\n", " "), part)
                   for i, part in enumerate(parts)).split("\n")


def _known_methods() -> tuple:
    """(shipped and baseline methods, those and the levers). The registry is one dict per
    process that a study adds its methods to when imported: a study's are in PROVIDERS."""
    from sim_bridge.benchmark.methods import METHODS, PROVIDERS
    import sim_bridge.studies.detection_levers  # noqa: F401  (registers the levers)
    return {m for m in METHODS if m not in PROVIDERS}, set(METHODS)


def test_the_method_checker_finds_a_lever_given_to_the_benchmark():
    shipped, with_levers = {"ours", "binary"}, {"ours", "binary", "ours_sure"}
    doc = ("`ros2 run sim_bridge benchmark --out R --methods ours,ours_sure --report` | x\n"
           "python -m sim_bridge.studies.detection_levers --out R \\\n  --methods ours_sure,binary\n"
           "python -m sim_bridge.studies.detection_levers paired_run R --methods ours_told\n"
           "python -m sim_bridge.benchmark.clutter_benchmark --methods ours_typo\n"
           "ros2 run sim_bridge benchmark --model ours_new=m.pt --methods ours_new; a `ros2 run sim_bridge\n"
           "benchmark --out R --methods\nbinary_scored` wrapped by the prose\n")
    assert unknown_methods(doc, "x.md", shipped, with_levers) == [
        "x.md: ros2 run sim_bridge benchmark --methods ours_sure: unknown method "
        "(a lever: python -m sim_bridge.studies.detection_levers)",
        "x.md: python -m sim_bridge.benchmark.clutter_benchmark --methods ours_typo: unknown method",
        "x.md: ros2 run sim_bridge benchmark --methods binary_scored: unknown method"]


def test_every_benchmark_command_names_methods_it_knows():
    """A reader who reruns a doc's benchmark command (e.g. a report on committed rounds) gets
    "unknown method" for a lever given to the product's benchmark."""
    shipped, with_levers = _known_methods()
    recipes = sorted(str(p.relative_to(ROOT)) for p in (ROOT / "sim_bridge" / "chains").glob("*.sh"))
    problems = [p for f in recipes + markdown_files() + ["Makefile"]
                for p in unknown_methods((ROOT / f).read_text(), f, shipped, with_levers)]
    assert not problems, f"{len(problems)} benchmark commands name a method they do not know:\n" + "\n".join(problems)
