"""The annotation page as a marimo app, served by ``s2p annotate`` (``marimo run``).

Each browser tab gets its own run of these cells (its own Session); the first tab edits, a
second one on the same project is read-only (see controller.Controller.open)."""

import marimo

app = marimo.App(width="full", app_title="s2p annotate")


@app.cell
def _():
    import os

    os.environ.setdefault("RERUN_NOTEBOOK_ASSET", "serve-local")
    import marimo as mo

    from annotate.app.session import session_from_env
    from seg2pose.core.errors import S2PError

    try:
        session = session_from_env()
        problem = None
    except S2PError as e:
        session, problem = None, str(e)
    except Exception as e:  # shown on the page rather than a blank one; the log has the rest
        import traceback

        traceback.print_exc()
        session, problem = None, f"{type(e).__name__}: {e} (see the server log)"
    return mo, problem, session


@app.cell
def _(mo, problem, session):
    page = (mo.callout(mo.md(f"**cannot open the project**: {problem}"), kind="danger")
            if session is None else
            mo.hstack([mo.vstack([session.frame_view, session.viewer]), session.panel],
                      widths=[3, 1], align="start"))
    page  # noqa: B018 -- marimo shows a cell's last expression
    return


if __name__ == "__main__":
    app.run()
