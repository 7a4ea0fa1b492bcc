"""A synthetic masseter with fascicles and aponeuroses, on an embedding and on a conforming
FEM (the seed paper's section 4.2)."""
