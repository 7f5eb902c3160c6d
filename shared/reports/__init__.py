"""Measured reports: the recognition report against its peers (``evaluation``,
``evaluation_report``: ``mirrorcoach evaluate recognition``) and studies with people
(``study``: ``mirrorcoach study``). Imports the library below it, never the bus."""
