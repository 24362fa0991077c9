// Plate with a circular hole: the rectangle (0,2) x (0,1) minus the disc of
// radius 0.25 centred at (1, 0.5).  No characteristic lengths are set: parefg
// sizes the mesh from the scene's h (Mesh.MeshSizeMax = h).
// Boundary parts (physical curves): "bottom", "top", "sides", "hole".
SetFactory("Built-in");

lx = 2.0;  ly = 1.0;             // plate size
cx = 1.0;  cy = 0.5;  r = 0.25;  // hole centre and radius

Point(1) = {0, 0, 0};
Point(2) = {lx, 0, 0};
Point(3) = {lx, ly, 0};
Point(4) = {0, ly, 0};
Line(1) = {1, 2};  // bottom
Line(2) = {2, 3};  // right side
Line(3) = {3, 4};  // top
Line(4) = {4, 1};  // left side

// The hole as four quarter arcs around its centre.
Point(5) = {cx, cy, 0};
Point(6) = {cx + r, cy, 0};
Point(7) = {cx, cy + r, 0};
Point(8) = {cx - r, cy, 0};
Point(9) = {cx, cy - r, 0};
Circle(5) = {6, 5, 7};
Circle(6) = {7, 5, 8};
Circle(7) = {8, 5, 9};
Circle(8) = {9, 5, 6};

Curve Loop(1) = {1, 2, 3, 4};
Curve Loop(2) = {5, 6, 7, 8};
Plane Surface(1) = {1, 2};

Physical Curve("bottom") = {1};
Physical Curve("top") = {3};
Physical Curve("sides") = {2, 4};
Physical Curve("hole") = {5, 6, 7, 8};
Physical Surface("plate") = {1};
