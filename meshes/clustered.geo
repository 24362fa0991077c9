// Clustered nodes: the unit square (0,1)^2 with the mesh refined towards the
// point (0.5, 0): the size grows linearly from h/4 within 0.05 of that point
// to h at distance 0.5 and beyond (a Distance + Threshold background field).
// h is the scene's h: parefg sets Mesh.MeshSizeMax = h before reading this file.
// Boundary parts (physical curves): "bottom", "right", "top", "left".
SetFactory("Built-in");

h = Mesh.MeshSizeMax;

Point(1) = {0, 0, 0};
Point(2) = {1, 0, 0};
Point(3) = {1, 1, 0};
Point(4) = {0, 1, 0};
Point(5) = {0.5, 0, 0};  // the cluster centre, on the bottom edge
Line(1) = {1, 5};
Line(2) = {5, 2};
Line(3) = {2, 3};
Line(4) = {3, 4};
Line(5) = {4, 1};
Curve Loop(1) = {1, 2, 3, 4, 5};
Plane Surface(1) = {1};

Field[1] = Distance;
Field[1].PointsList = {5};
Field[2] = Threshold;
Field[2].InField = 1;
Field[2].SizeMin = h / 4;
Field[2].SizeMax = h;
Field[2].DistMin = 0.05;
Field[2].DistMax = 0.5;
Background Field = 2;

Physical Curve("bottom") = {1, 2};
Physical Curve("right") = {3};
Physical Curve("top") = {4};
Physical Curve("left") = {5};
Physical Surface("square") = {1};
