"""The airway: a skin over the tongue, the jaw and the palate, loaded by the air inside it
(the seed paper's section 4.1)."""
