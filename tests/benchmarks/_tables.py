"""What the tests of the benchmarks that write a table into a page share."""

from __future__ import annotations

from softpvtol_gym.baselines.util.blocks import read_block


def check_render_only(bench, committed: dict, tmp_path, capsys) -> None:
    """``bench.main(["--render-only", "--doc", page])`` writes ``bench.markdown_table(committed)`` between the
    page's markers of ``bench.BLOCK`` and says so."""
    doc = tmp_path / "page.md"
    start, end = (f"<!-- {bench.BLOCK}: table start (generated from {bench.SOURCE}, do not edit) -->",
                  f"<!-- {bench.BLOCK}: table end -->")
    doc.write_text(f"# x\n\n{start}\nold\n{end}\n")
    assert bench.main(["--render-only", "--doc", str(doc)]) == 0
    assert read_block(bench.BLOCK, bench.SOURCE, doc) == bench.markdown_table(committed).strip()
    assert "wrote the table" in capsys.readouterr().out
