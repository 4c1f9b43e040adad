"""List the C++ functions and classes longer than the project's size limits (issue 35: functions
<= 60 lines, classes <= 220), counted from the line of the signature's first token to the closing
brace, comments and blank lines included.

    python tools/cpp_sizes.py [PATH ...] [--functions 60] [--classes 220] [--all]

PATH: files or directories (default the repository's cpp/include). Exit status 1 when something is
over, so it can serve as a check. A brace scanner, not a parser: comments, preprocessor lines,
strings and character literals are skipped; a brace at namespace or class scope opens a class (class/struct/union after any
template <...>), a namespace, a function (its head has a parenthesis) or something else (an enum,
a brace initializer: skipped whole). Lambdas and local classes count towards their function.
"""
import argparse
import pathlib
import re
import sys


def strip(text):
    """The text with comments, preprocessor lines, string and char literals blanked (newlines kept)."""
    out, i, n = [], 0, len(text)
    while i < n:
        c = text[i]
        if c == "#" and text[text.rfind("\n", 0, i) + 1:i].strip() == "":
            j = i
            while True:
                j = text.find("\n", j)
                if j < 0 or text[j - 1] != "\\":
                    break
                j += 1
            j = n if j < 0 else j
            out.append(re.sub(r"[^\n]", " ", text[i:j])); i = j
        elif text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append(" " * (j - i)); i = j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            j = n if j < 0 else j + 2
            out.append(re.sub(r"[^\n]", " ", text[i:j])); i = j
        elif c == 'R' and text.startswith('R"', i):
            m = re.match(r'R"([^(]*)\(', text[i:])
            end = text.find(")" + m.group(1) + '"', i) + len(m.group(1)) + 2
            out.append(re.sub(r"[^\n]", " ", text[i:end])); i = end
        elif c in "\"'" and not (c == "'" and i > 0 and text[i - 1].isalnum()):  # 1'000 separators
            j = i + 1
            while j < n and text[j] != c:
                j += 2 if text[j] == "\\" else 1
            out.append(" " * (j + 1 - i)); i = j + 1
        else:
            out.append(c); i += 1
    return "".join(out)


def drop_templates(head):
    """The head without leading `template <...>` clauses and [[attributes]]."""
    head = head.strip()
    while True:
        head = re.sub(r"^\[\[.*?\]\]\s*", "", head)
        m = re.match(r"template\s*<", head)
        if not m:
            return head
        depth, i = 1, m.end()
        while i < len(head) and depth:
            depth += {"<": 1, ">": -1}.get(head[i], 0)
            i += 1
        head = head[i:].strip()


def kind(head):
    h = drop_templates(head)
    first = h.split(None, 1)[0] if h.split() else ""
    if first in ("namespace", "extern"):
        return "namespace"
    if first in ("class", "struct", "union"):
        return "class"
    if first == "enum" or "(" not in h or h.count("(") > h.count(")"):
        return "other"        # an enum, an initializer (x{1}, a default argument f(T t = {}))
    tail = re.sub(r"(\s*\b(const|noexcept|override|final|mutable|volatile)\b|\s*&&?)+$", "", h)
    if tail.endswith(")") or re.search(r"->\s*[\w:<>,\s*&]+$", tail):
        return "function"
    if tail.endswith("}") and re.search(r"\)\s*(noexcept\s*)?:(?!:)", h):
        return "function"     # a constructor whose list ends in a brace initializer: c_{} {
    return "other"            # a member's brace initializer in a constructor's list: a_{x}


def name_of(head, k):
    h = " ".join(drop_templates(head).split())
    if k == "class":
        return h.split()[1] if len(h.split()) > 1 else h
    m = re.search(r"(operator\s*\S+?|~?[\w:]+)\s*\(", h)
    return m.group(1) if m else h[:40]


def scan(path):
    """(kind, name, first line, last line) of every class and function in a file."""
    text = strip(pathlib.Path(path).read_text())
    found, stack = [], []          # stack: (kind, name, start line) of open braces
    head, head_line = "", None
    line = 1
    for i, c in enumerate(text):
        if c == "\n":
            line += 1
        scope = stack[-1][0] if stack else "namespace"
        inside_body = any(s[0] in ("function", "other") for s in stack)
        if c == "{":
            if inside_body:
                stack.append(("inner", None, line))
                continue
            k = kind(head)
            stack.append((k, name_of(head, k), head_line or line))
            if k != "other":
                head, head_line = "", None
        elif c == "}":
            k, name, start = stack.pop()
            if k in ("class", "function"):
                found.append((k, name, start, line))
            if not any(s[0] in ("function", "other") for s in stack):
                if k == "other":       # a brace initializer: the head goes on (x{1}, y(2) {)
                    head += "{}"
                else:
                    head, head_line = "", None
        elif not inside_body and scope in ("namespace", "class"):
            if c == ";" or (c == ":" and re.search(r"\b(public|private|protected)\s*$", head)):
                head, head_line = "", None
            elif not c.isspace():
                if head_line is None:
                    head_line = line
                head += c
            else:
                head += c
    return found


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("paths", nargs="*", default=[str(pathlib.Path(__file__).resolve().parent.parent / "cpp" / "include")])
    ap.add_argument("--functions", type=int, default=60)
    ap.add_argument("--classes", type=int, default=220)
    ap.add_argument("--all", action="store_true", help="list every class and function with its size")
    a = ap.parse_args()
    files = []
    for p in map(pathlib.Path, a.paths):
        files += sorted(p.rglob("*.hpp")) + sorted(p.rglob("*.cpp")) if p.is_dir() else [p]
    over = 0
    for f in files:
        for k, name, start, end in scan(f):
            size = end - start + 1
            limit = a.functions if k == "function" else a.classes
            if size > limit or a.all:
                over += size > limit
                print(f"{f}:{start}: {k} {name} {size} lines" + (f" (> {limit})" if size > limit else ""))
    return 1 if over else 0


if __name__ == "__main__":
    sys.exit(main())
