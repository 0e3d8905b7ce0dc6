#!/usr/bin/env bash
# The documentation stands alone (issue 16): nothing in the repository points at the
# maintainers' notes outside it (../shared/), every relative link in README.md and docs/*.md
# reaches a file (and a heading, for #anchors) in the repository, and neither docs/*.md nor a
# user-visible string in the code (estimator summaries, parameter help) cites the internal
# MODEL.md; docs/model.md holds the physics instead.
set -euo pipefail
SRC="$(cd "$1" && pwd)"
exec /usr/bin/python3 - "$SRC" <<'PY'
import os, re, sys

src = sys.argv[1]
skip_dirs = {".git", "node_modules", "vendor"}
this = os.path.join(src, "tests", "docs_links.sh")
text_ext = (".md", ".cpp", ".hpp", ".h", ".js", ".mjs", ".html", ".css", ".json", ".sh", ".py",
            ".txt", ".cmake")

def files():
    for root, dirs, names in os.walk(src):
        dirs[:] = [d for d in dirs if d not in skip_dirs and not d.startswith("build")]
        for n in names:
            p = os.path.join(root, n)
            if (n.endswith(text_ext) or n in ("CMakeLists.txt",)) and p != this:
                yield p

def rel(p):
    return os.path.relpath(p, src)

bad = []
# 1. No pointer outside the repository to the shared notes.
for p in files():
    for i, line in enumerate(open(p, encoding="utf-8", errors="replace"), 1):
        if "../shared/" in line:
            bad.append(f"{rel(p)}:{i}: points outside the repository: {line.strip()[:120]}")

# 2. Relative links in README.md and docs/*.md resolve; #anchors name a heading.
def slug(heading):
    s = heading.strip().lower()
    s = re.sub(r"[^\w\- ]", "", s)  # GitHub: drop punctuation, keep letters, digits, -, _
    return s.replace(" ", "-")

def anchors(md):
    out, fence = set(), False
    for line in open(md, encoding="utf-8"):
        if line.startswith("```"):
            fence = not fence
        elif not fence and re.match(r"#{1,6} ", line):
            out.add(slug(line.lstrip("#")))
    return out

docs = [os.path.join(src, "README.md")] + sorted(
    os.path.join(src, "docs", n) for n in os.listdir(os.path.join(src, "docs")) if n.endswith(".md"))
link = re.compile(r"\]\(([^)\s]+)\)")
for md in docs:
    fence = False
    for i, line in enumerate(open(md, encoding="utf-8"), 1):
        if line.startswith("```"):
            fence = not fence
        if fence:
            continue
        for target in link.findall(line):
            if re.match(r"[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto:
                continue
            path, _, anchor = target.partition("#")
            dest = os.path.normpath(os.path.join(os.path.dirname(md), path)) if path else md
            if not dest.startswith(src + os.sep) and dest != src:
                bad.append(f"{rel(md)}:{i}: link leaves the repository: {target}")
            elif not os.path.exists(dest):
                bad.append(f"{rel(md)}:{i}: broken link: {target}")
            elif anchor and dest.endswith(".md") and anchor not in anchors(dest):
                bad.append(f"{rel(md)}:{i}: no heading for #{anchor} in {rel(dest)}")

# 3. Users cannot read MODEL.md: the docs (other than model.md's map of source comments) and
# the strings the code shows (estimator summaries, parameter help) must not cite it.
for md in docs:  # README included
    if os.path.basename(md) == "model.md":
        continue
    for i, line in enumerate(open(md, encoding="utf-8"), 1):
        if "MODEL.md" in line:
            bad.append(f"{rel(md)}:{i}: cites MODEL.md, which users do not have (link docs/model.md): {line.strip()[:100]}")
literal = re.compile(r'"[^"\n]*MODEL\.md')
for p in files():  # fixture descriptions are shown in the UI and the CLI
    if rel(p).split(os.sep)[0] == "fixtures":
        for i, line in enumerate(open(p, encoding="utf-8"), 1):
            if "MODEL.md" in line:
                bad.append(f"{rel(p)}:{i}: a fixture cites MODEL.md: {line.strip()[:100]}")
for p in files():
    r = rel(p)
    if not r.split(os.sep)[0] in ("server", "estimator", "signal_gen", "drivers", "web") or not p.endswith((".cpp", ".hpp", ".js", ".html")):
        continue
    for i, line in enumerate(open(p, encoding="utf-8"), 1):
        code = line.split("//")[0] if not line.lstrip().startswith(("//", "*", "/*")) else ""
        if literal.search(code):
            bad.append(f"{r}:{i}: a user-visible string cites MODEL.md: {line.strip()[:100]}")

for b in bad:
    print(b)
if bad:
    sys.exit(f"docs.links: {len(bad)} problem(s)")
print(f"docs.links OK ({len(docs)} Markdown files)")
PY
