"""Motion primitives: DMP maths, re-targeting maps, the dictionary, learning from demonstrations."""
