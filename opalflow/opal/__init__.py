"""Inverse-opal scene (kind = "opal", Dosta et al. section 2.1): packing, pores, coating, substrate, statistics."""
