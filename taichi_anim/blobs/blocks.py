"""The blob grid's tiling into blocks of BLOCK^3 nodes: the unit of work of the field's evaluation (only
blocks near particles are flagged and visited) and of the marching tetrahedra (counts and offsets per
block). Its own module so that the field and its extractors share it without importing each other."""

BLOCK = 8  # nodes per block edge: 512 nodes, a unit of work big enough to hide the loop overhead
BLOCK3 = BLOCK**3
