"""The annotation app (``s2p annotate SCENE``): a local web page served by marimo with the Rerun
notebook viewer and a panel of actions, on top of the engine.

controller.py  state, no UI imports (unit-tested without a browser), with the mixins
actions.py     the panel's actions and shortcuts
clicks.py      clicks in the views
panel_data.py  what the panel shows, as data
panel.py       the panel widget (HTML from the controller, keys and buttons back)
session.py     one page: controller + viewer + panel wired together
notebook.py    the marimo app file
serve.py       starts ``marimo run`` for ``s2p annotate``
"""
