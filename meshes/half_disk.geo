// Half-disk for the Hertz line-contact verification (scripts/verify/hertz_study.py):
// the lower half of the disc of radius R = 1 centred at (0, 1), i.e. the region
// y <= 1 inside that circle.  Its curved boundary touches the plane y = 0 at the
// origin; its flat top is y = 1.
// The mesh is graded by a Distance + Threshold field from h/10 within 0.15 of the
// origin (the contact zone of a half-width up to ~0.12) to h beyond distance 0.6.
// h is the scene's h: parefg sets Mesh.MeshSizeMax = h before reading this file.
// Boundary parts (physical curves):
//   "contact": the arc within 30 degrees of the lowest point (|x| <= 0.5);
//   "free":    the rest of the arc (traction-free);
//   "top":     the flat top y = 1.
SetFactory("Built-in");

h = Mesh.MeshSizeMax;
R = 1.0;
c = Cos(Pi / 6);
s = Sin(Pi / 6);

Point(1) = {0, R, 0};             // the centre
Point(2) = {-R, R, 0};            // left end of the top
Point(3) = {-R * s, R - R * c, 0};
Point(4) = {0, 0, 0};             // the lowest point, where contact starts
Point(5) = {R * s, R - R * c, 0};
Point(6) = {R, R, 0};             // right end of the top

Circle(1) = {2, 1, 3};
Circle(2) = {3, 1, 4};
Circle(3) = {4, 1, 5};
Circle(4) = {5, 1, 6};
Line(5) = {6, 2};
Curve Loop(1) = {1, 2, 3, 4, 5};
Plane Surface(1) = {1};

Field[1] = Distance;
Field[1].PointsList = {4};
Field[2] = Threshold;
Field[2].InField = 1;
Field[2].SizeMin = h / 10;
Field[2].SizeMax = h;
Field[2].DistMin = 0.15;
Field[2].DistMax = 0.6;
Background Field = 2;

Physical Curve("contact") = {2, 3};
Physical Curve("free") = {1, 4};
Physical Curve("top") = {5};
Physical Surface("half_disk") = {1};
