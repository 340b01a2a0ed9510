"""The README and the docs quote the statistics tier's report (docs/validation.md, written by
``pytest -m stats``) and agree with it. A figure linked as ``[0.94](docs/validation.md#name "key")``
is the report's ``key`` of figure ``name`` at the precision printed (a range ``a-b`` is a list's
smallest and largest), from a test that passed; a link without a key cites a claim that the tier
asserted and that passed."""

import math
import pathlib
import re

import pytest
import validation

ROOT = pathlib.Path(__file__).resolve().parent.parent
CITE = re.compile(r'\[([^\]]+)\]\((?:docs/)?validation\.md#([\w-]+)(?: "([^"]+)")?\)')
NUMBER = r"\d+(?:\.\d+)?"


def _pages() -> list[pathlib.Path]:
    return [ROOT / "README.md", *sorted(p for p in (ROOT / "docs").rglob("*.md") if p.name != "validation.md")]


def citations() -> list[tuple[str, str, str, str | None]]:
    """``(page, printed, anchor, key)`` of every link into the report, README and docs."""
    return [(p.name, *m.groups()) for p in _pages() for m in CITE.finditer(p.read_text())]


def agrees(printed: str, reported: str) -> bool:
    """Whether ``printed`` (``0.94``, ``1.5-1.8``) is ``reported`` (the report's ``0.9388`` or
    list ``0.959, 0.878, ...``) rounded as printed: each printed number within half its own last
    digit, plus the report's own rounding to 4 significant digits."""
    match = re.fullmatch(f"({NUMBER})(?:-({NUMBER}))?", printed.strip())
    if match is None:
        raise ValueError(f"a cited figure must be a number or a range a-b, got {printed!r}")
    values = [float(v) for v in reported.split(", ")]
    wanted = [w for w in match.groups() if w is not None]
    if len(wanted) == 1 and len(values) != 1 or not all(math.isfinite(v) for v in values):
        return False
    got = values if len(wanted) == 1 else [min(values), max(values)]

    def close(text, v):
        digits = len(text.partition(".")[2])
        own = 0.5 * 10 ** (math.floor(math.log10(abs(v))) - 3) if v else 0.0
        return abs(float(text) - v) <= 0.5 * 10**-digits + own + 1e-12

    return all(close(w, v) for w, v in zip(wanted, got, strict=True))


def test_agreement_is_at_the_printed_precision():
    assert agrees("0.94", "0.9388") and not agrees("0.93", "0.9388") and not agrees("0.939", "0.9377")
    assert agrees("0.88-0.98", "0.959, 0.878, 0.98") and not agrees("0.90-0.98", "0.959, 0.878, 0.98")
    assert agrees("49", "49") and not agrees("50", "49") and not agrees("0.9", "0.9, 0.95")
    assert not agrees("1-1.5", "0.95, 1.31") and agrees("0.95-2", "0.95, 1.8")  # each number its own digits
    assert not agrees("0.1", "inf") and not agrees("0.1", "nan")
    with pytest.raises(ValueError, match="about 0.9"):
        agrees("about 0.9", "0.9")


def test_the_readme_quotes_the_report_and_every_link_to_it_is_read():
    assert sum(page == "README.md" for page, *_ in citations()) >= 5
    for page in _pages():  # a link this test cannot parse would pass unchecked
        text = page.read_text()
        assert text.count("validation.md#") == len(CITE.findall(text)), f"{page.name}: a link into the report unread"


@pytest.mark.parametrize("page, printed, anchor, key", citations())
def test_a_quoted_figure_is_the_reports(page, printed, anchor, key):
    report = validation.read()
    assert anchor in report, f"{page} cites {anchor}, which docs/validation.md does not hold"
    figure = report[anchor]
    assert figure["outcome"] == "passed", f"{page} cites {figure['name']}, whose test {figure['outcome']}"
    if key is not None:
        assert key in figure["figures"], f"{page} cites {key!r} of {figure['name']}: not in {sorted(figure['figures'])}"
        reported = figure["figures"][key]
        assert agrees(printed, reported), f"{page} prints {printed} for {anchor} {key}; the report: {reported}"
