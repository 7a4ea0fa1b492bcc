"""The styloglossus as two external point-to-point muscles on the tongue: 4 versus 24
support nodes (the seed paper's section 3.1)."""
