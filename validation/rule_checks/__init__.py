"""The checks of the verdict's rules (registered in :mod:`validation.rules`): the comparisons with a
baseline (:mod:`.compare`) and what limits a bias beyond them (:mod:`.limitations`). A new rule's check
is a module here: ``check(ev: Evidence) -> list[str]``, one text per time it fires."""
