"""A self-contained HTML report: sections of text, tables and figures (PNG embedded as base64)."""
from __future__ import annotations

import base64
import html
from dataclasses import dataclass, field
from pathlib import Path

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1100px;margin:2em auto;
padding:0 1em;color:#1b1f24;line-height:1.45}
h1{font-size:1.7em;margin-bottom:.2em}h2{font-size:1.25em;border-bottom:1px solid #d0d7de;padding-bottom:.2em;
margin-top:2em}.meta{color:#57606a}table{border-collapse:collapse;margin:.6em 0}
td,th{border:1px solid #d0d7de;padding:.25em .6em;text-align:right}th{background:#f6f8fa}
td:first-child,th:first-child{text-align:left}figure{margin:1em 0}img{max-width:100%;border:1px solid #eee}
figcaption{color:#57606a;font-size:.9em}.ok{color:#1a7f37;font-weight:600}.bad{color:#cf222e;font-weight:600}
pre{background:#f6f8fa;padding:.6em;overflow-x:auto;font-size:.85em}
"""


@dataclass
class Section:
    title: str
    parts: list = field(default_factory=list)

    def text(self, s: str) -> "Section":
        self.parts.append(f"<p>{html.escape(s)}</p>")
        return self

    def pre(self, s: str) -> "Section":
        self.parts.append(f"<pre>{html.escape(s)}</pre>")
        return self

    def verdict(self, ok: bool, s: str) -> "Section":
        cls = "ok" if ok else "bad"
        self.parts.append(f'<p class="{cls}">{"✔" if ok else "✘"} {html.escape(s)}</p>')
        return self

    def table(self, header: list[str], rows: list[list], caption: str | None = None) -> "Section":
        def cell(v):
            if isinstance(v, float):  # 4 significant digits, 6 for large values (3450.05, 164.810)
                return f"{v:.4g}" if abs(v) < 100 else f"{v:.6g}"
            return html.escape(str(v))
        h = "".join(f"<th>{html.escape(str(x))}</th>" for x in header)
        body = "".join("<tr>" + "".join(f"<td>{cell(v)}</td>" for v in r) + "</tr>" for r in rows)
        cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
        self.parts.append(f"<table>{cap}<tr>{h}</tr>{body}</table>")
        return self

    def figure(self, png: str | Path, caption: str = "") -> "Section":
        data = base64.b64encode(Path(png).read_bytes()).decode("ascii")
        self.parts.append(f'<figure><img alt="{html.escape(caption)}" src="data:image/png;base64,{data}">'
                          f"<figcaption>{html.escape(caption)}</figcaption></figure>")
        return self


def render(title: str, meta: str, sections: list[Section]) -> str:
    body = "".join(f"<h2>{html.escape(s.title)}</h2>{''.join(s.parts)}" for s in sections)
    return (f"<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{html.escape(title)}</title>"
            f"<style>{_CSS}</style></head><body><h1>{html.escape(title)}</h1><p class=\"meta\">{html.escape(meta)}</p>"
            f"{body}</body></html>\n")
