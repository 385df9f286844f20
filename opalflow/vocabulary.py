"""Names that more than one track reads, so that none imports another for them: the aerogel track builds its
networks with a loop model (:mod:`opalflow.aerogel.loops`), the studies sweep them (``study.loop_models``)."""

#: how loops are closed in an aerogel's network (opalflow.aerogel.loops)
LOOP_MODELS = ("none", "deflection", "restructuring", "necks")
