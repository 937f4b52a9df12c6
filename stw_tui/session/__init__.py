"""A session: the interpreter that applies command lines to a scene, the journal, undo and snapshots,
autosave and resume, previews, surveys, and queries (show, figures, exports). Imports ``sym`` and
``sos``; no Textual."""
