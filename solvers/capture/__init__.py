"""The actor's side of a take: cleaning, stabilisation (head motion removed), the neutral and
normalisation, and the actor-to-character alignment. Plain functions on ``MarkerSet``s."""
