"""The animator feedback loop: corrected frames re-optimise what a strategy learned (``retune``),
at take level (``take.retune_take``), with every version kept (``store``)."""
