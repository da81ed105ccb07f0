"""The operator console: `normbox-lab tui` (docs/tui.md).

`controller.Session` (the lab, the store, one engine run in a worker thread; no Textual) and
`app.NormboxConsole` (the Textual app).  Import `app` only where Textual is wanted.
"""
