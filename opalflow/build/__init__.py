"""Structure generators: packing, pores, coating, substrate, bonds."""
