"""Evaluation on the test split (the paper's protocol): the test windows (:mod:`.windows`), the
evaluation of a trained run or a reference row (:mod:`.evaluate`), its output folder (:mod:`.outputs`,
:mod:`.predictions`), Table I (:mod:`.table`) and the paper's published rows beside it (:mod:`.paper`)."""
