"""The docs a technician follows: README.md is a front page of at most 250 lines; every
relative link in README.md and docs/*.md leads to a file (and a heading) that exists; every
command in the sh/console blocks of README.md and docs/commissioning.md runs as shown.

Commands that end (``compgw check``) run as shown. Commands that run for hours (``compgw
run``, ``compgw sim``, ``make demo``, a commissioning) are checked instead: the subcommand's
``--help`` names every option the doc gives, compgw's own parser takes the whole line, a
commissioning runs with ``--dry-run`` (its plan, nothing moved), ``compgw status`` runs
against a loopback port where no gateway listens, ``make`` runs with ``-n``. A config path
under ``/etc`` (the site's file) is stood in for by a copy of config/example.yaml.
"""

from __future__ import annotations

import contextlib
import io
import re
import shlex
import shutil
import socket
import subprocess
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import pytest

from gateway.cli import build_parser
from tests.test_check_cli import _compgw

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DOCS = ROOT / "docs"
COMMAND_DOCS = (README, DOCS / "commissioning.md")
PROGRAMS = ("compgw", ".venv/bin/compgw", "make", "mbpoll")
SHELL_BLOCKS = ("sh", "console", "shell", "bash")
FENCE = re.compile(r"^(\s*)(```|~~~)\s*([\w+-]*)")
# what the front page's comments promise each make target runs
MAKE_RUNS = {"demo": ("compgw demo",), "test": ("ruff check", "pytest")}


def _docs() -> list[Path]:
    return [README, *sorted(DOCS.glob("*.md"))]


def _name(path: Path) -> str:
    return str(path.relative_to(ROOT))


def _prose(text: str) -> str:
    """The text outside fenced code blocks (their lines blanked: line numbers stay)."""
    lines, fence = [], None
    for line in text.splitlines():
        match = FENCE.match(line)
        if fence is None and match:
            fence = match.group(2)
            lines.append("")
        elif fence is not None:
            if line.strip().startswith(fence):
                fence = None
            lines.append("")
        else:
            lines.append(line)
    return "\n".join(lines)


def _slug(heading: str) -> str:
    """GitHub's anchor for a heading: its text lower-cased, punctuation but ``-`` and ``_``
    dropped, spaces made hyphens."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading).replace("`", "").strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    seen: Counter[str] = Counter()
    anchors = set()
    for line in _prose(path.read_text(encoding="utf-8")).splitlines():
        match = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if match:
            slug = _slug(match.group(1))
            anchors.add(slug if not seen[slug] else f"{slug}-{seen[slug]}")
            seen[slug] += 1
    return anchors


def _links(path: Path) -> list[tuple[int, str]]:
    """``(line, target)`` of every inline link and image outside code."""
    text = _prose(path.read_text(encoding="utf-8"))
    text = re.sub(r"`[^`]*`", lambda m: re.sub(r"[^\n]", " ", m.group(0)), text)
    return [(text.count("\n", 0, m.start()) + 1, m.group(1))
            for m in re.finditer(r"\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)", text)]


@dataclass(frozen=True)
class Command:
    doc: Path
    line: int  # where it starts in the doc
    text: str  # as shown (continuations joined)
    argv: tuple[str, ...]

    def where(self) -> str:
        return f"{_name(self.doc)}:{self.line}: `{self.text}`"


def _commands(path: Path) -> list[Command]:
    """The command lines of the sh/console blocks that start with one of PROGRAMS."""
    found: list[Command] = []
    lines = path.read_text(encoding="utf-8").splitlines()
    i = 0
    while i < len(lines):
        match = FENCE.match(lines[i])
        i += 1
        if not match:
            continue
        indent, fence, info = match.groups()
        block: list[tuple[int, str]] = []
        while i < len(lines) and not lines[i].strip().startswith(fence):
            block.append((i + 1, lines[i].removeprefix(indent)))
            i += 1
        i += 1
        if info not in SHELL_BLOCKS:
            continue
        j = 0
        while j < len(block):
            start, text = block[j]
            while text.rstrip().endswith("\\") and j + 1 < len(block):
                j += 1
                text = text.rstrip()[:-1].rstrip() + " " + block[j][1].strip()
            j += 1
            text = text.strip().removeprefix("$ ")
            argv = tuple(shlex.split(text, comments=True))
            if argv and argv[0] in PROGRAMS:
                found.append(Command(path, start, text, argv))
    return found


COMMANDS = [c for doc in COMMAND_DOCS for c in _commands(doc)]


def test_readme_is_a_front_page() -> None:
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 250, f"README.md: {len(lines)} lines, at most 250 (move text to docs/)"
    assert lines[0].startswith("# compgw"), "README.md: the title first"
    first_block = next(i for i, line in enumerate(lines) if line.startswith("```"))
    assert lines[first_block:first_block + 4] == [
        "```sh",
        "make demo    # sets up .venv, installs, runs `compgw demo` (sim + gateway + scripted "
        "master)",
        "make test    # sets up .venv, installs, runs ruff and the whole test suite",
        "```",
    ], "README.md: the two commands open the page"
    assert "docs/service-and-security.md#safety-notes" in "\n".join(lines), \
        "README.md: the front page links the safety notes"


def test_every_guide_is_in_the_index() -> None:
    index = {target.split("#")[0] for _, target in _links(DOCS / "README.md")}
    missing = [p.name for p in DOCS.glob("*.md") if p.name != "README.md" and p.name not in index]
    assert not missing, f"docs/README.md: no link to {', '.join(missing)}"


def test_every_relative_link_leads_somewhere() -> None:
    problems = []
    for doc in _docs():
        for line, target in _links(doc):
            if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I):  # http:, mailto:
                continue
            where = f"{_name(doc)}:{line}: link {target}"
            file, _, anchor = target.partition("#")
            path = (doc.parent / file).resolve() if file else doc
            if not path.exists():
                problems.append(f"{where}: no file {path.relative_to(ROOT)}")
            elif anchor and (path.suffix != ".md" or anchor not in _anchors(path)):
                problems.append(f"{where}: no heading #{anchor} in {_name(path)}")
    assert not problems, "\n".join(problems)


def test_the_docs_show_commands() -> None:
    """The extraction itself: both docs have commands to check (a fence renamed, a prompt
    changed, and the checks below would pass on nothing)."""
    for doc in COMMAND_DOCS:
        assert any(c.doc == doc for c in COMMANDS), f"{_name(doc)}: no command found in sh blocks"
    assert any(c.argv[0] == "make" for c in COMMANDS), "README.md: `make demo` not found"


def test_compgw_is_the_entry_point_the_tests_call() -> None:
    """The commands below run ``gateway.cli.main`` in this process: it is what the installed
    ``compgw`` (and ``.venv/bin/compgw``, which make installs) runs."""
    text = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    assert re.search(r'^compgw = "gateway\.cli:main"$', text, re.M), "pyproject.toml: scripts"


def _site_config(tmp_path: Path) -> Path:
    """A stand-in for the site's /etc/compgw/compgw.yaml: the example and its tables, with
    status.remote_control on as the commissioning guide's steps have you set it."""
    site = tmp_path / "site"
    site.mkdir(exist_ok=True)
    shutil.copytree(ROOT / "config" / "tables", site / "tables", dirs_exist_ok=True)
    text = (ROOT / "config" / "example.yaml").read_text()
    assert "remote_control: false" in text
    (site / "compgw.yaml").write_text(text.replace("remote_control: false",
                                                   "remote_control: true"))
    return site / "compgw.yaml"


def _options(argv: tuple[str, ...], digits: bool = False) -> list[str]:
    """The options a command line gives (``-0``, ``-1`` too with ``digits``: mbpoll's)."""
    first = "A-Za-z0-9" if digits else "A-Za-z"
    return [a.split("=")[0] for a in argv if re.match(rf"^--?[{first}]", a)]


def _check_compgw(cmd: Command, tmp_path: Path) -> None:
    argv = list(cmd.argv[1:])
    sub = argv[0]
    helped = _compgw(sub, "--help")
    assert helped.returncode == 0, f"{cmd.where()}: `compgw {sub} --help` failed: {helped.stderr}"
    for option in _options(tuple(argv[1:])):
        assert re.search(rf"(?<![\w-]){re.escape(option)}(?![\w-])", helped.stdout), (
            f"{cmd.where()}: {option} is not in `compgw {sub} --help`")
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        try:
            build_parser(argv).parse_args(argv)
        except SystemExit as exc:
            pytest.fail(f"{cmd.where()}: compgw's parser refuses it ({exc.code}): {err.getvalue()}")
    for i, arg in enumerate(argv[:-1]):
        if arg in ("-c", "--config"):
            path = Path(argv[i + 1])
            if path.is_absolute():
                argv[i + 1] = str(_site_config(tmp_path))
            else:
                assert (ROOT / path).exists(), f"{cmd.where()}: no file {path} in the repository"
    if sub == "check":
        out = _compgw(*argv)
        assert out.returncode == 0, f"{cmd.where()}: exit {out.returncode}: {out.stderr}"
        assert out.stdout.strip(), f"{cmd.where()}: printed nothing"
    elif sub == "status":
        with socket.socket() as s:  # a loopback port just free: nobody listens there
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        out = _compgw(*argv, "--port", port)
        assert out.stderr.splitlines() == [f"compgw status: no gateway at 127.0.0.1:{port}"], (
            f"{cmd.where()} (--port {port}, no gateway there): exit {out.returncode}: "
            f"{out.stderr}")
    elif sub == "commission" and "--recheck" not in argv:
        if "--dry-run" not in argv:
            argv.append("--dry-run")
        out = _compgw(*argv)
        assert out.returncode == 0 and "first steps" in out.stdout, (
            f"{cmd.where()} (--dry-run): exit {out.returncode}: {out.stdout}{out.stderr}")


def _check_make(cmd: Command) -> None:
    if shutil.which("make") is None:
        pytest.skip("make is not installed")
    targets = [a for a in cmd.argv[1:] if not a.startswith("-")]
    out = subprocess.run(["make", "-n", "-C", str(ROOT), *targets], capture_output=True,
                         text=True, timeout=30)
    assert out.returncode == 0, f"{cmd.where()}: `make -n` exit {out.returncode}: {out.stderr}"
    for target in targets:
        for step in MAKE_RUNS.get(target, ()):
            assert step in out.stdout, f"{cmd.where()}: the recipe runs no `{step}`"


def _check_mbpoll(cmd: Command) -> None:
    comment = re.search(r"#\s*(0x[0-9A-Fa-f]+)", cmd.text)
    argv = list(cmd.argv)
    if comment and "-r" in argv:
        register = int(argv[argv.index("-r") + 1])
        assert register == int(comment.group(1), 16), (
            f"{cmd.where()}: -r {register} is {register:#06x}, the comment says "
            f"{comment.group(1)}")
    mbpoll = shutil.which("mbpoll")
    if mbpoll is None:
        pytest.skip("mbpoll is not installed (make test installs it with apt-get)")
    out = subprocess.run([mbpoll, "-h"], capture_output=True, text=True, timeout=30)
    usage = out.stdout + out.stderr
    for option in _options(cmd.argv[1:], digits=True):
        assert re.search(rf"(?<![\w-]){re.escape(option)}(?![\w-])", usage), (
            f"{cmd.where()}: {option} is not in `mbpoll -h`")


@pytest.mark.parametrize("cmd", COMMANDS, ids=[f"{_name(c.doc)}:{c.line}" for c in COMMANDS])
def test_each_command_runs_as_shown(cmd: Command, tmp_path: Path,
                                    monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(ROOT)  # the docs' paths are the repository's
    program = cmd.argv[0]
    if program.endswith("compgw"):
        _check_compgw(cmd, tmp_path)
    elif program == "make":
        _check_make(cmd)
    else:
        _check_mbpoll(cmd)
