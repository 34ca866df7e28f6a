"""Reading and writing: the whitelisted expression codec and the derivation cache."""
