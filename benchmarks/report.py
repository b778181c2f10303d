"""The benchmarks' tables: printed as they come, collected as Markdown (for the README and
benchmarks/results/)."""

from __future__ import annotations

from pathlib import Path


class Report:
    """Tables and lines printed as they come and collected as Markdown."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.lines: list[str] = []

    def text(self, line: str) -> None:
        print(line)
        self.lines += [line, ""]

    def table(self, title: str, head: list[str], rows: list[list[str]]) -> None:
        print(f"\n{title}")
        widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(head)]
        print("  ".join(h.rjust(w) for h, w in zip(head, widths)))
        for r in rows:
            print("  ".join(c.rjust(w) for c, w in zip(r, widths)))
        self.lines += [f"**{title}**", "", "| " + " | ".join(head) + " |",
                       "|" + "|".join("---:" for _ in head) + "|"]
        self.lines += ["| " + " | ".join(r) + " |" for r in rows]
        self.lines.append("")

    def save(self, name: str) -> Path:
        """Write the Markdown to ``out/name``; its path."""
        self.out.mkdir(parents=True, exist_ok=True)
        path = self.out / name
        path.write_text("\n".join(self.lines) + "\n")
        return path
