"""The annotation app (``s2p annotate SCENE``): a local web page served by marimo with the Rerun
notebook viewer and a panel of actions, on top of the engine.

controller.py  state and actions, no UI imports (unit-tested without a browser)
panel.py       the panel widget (HTML from the controller, keys and buttons back)
session.py     one page: controller + viewer + panel wired together
notebook.py    the marimo app file
serve.py       starts ``marimo run`` for ``s2p annotate``
"""
