// The six-fracture network of Berge et al. (2020, §4.3) used by Beaude et al. (2023, §3), the
// geometry of meshes/six_fractures.yaml, as a gmsh script (built-in kernel). poromech reads the
// fractures and the boundary parts from the physical curves below; the mesh sizes are those of
// configs/six_fractures_mechanics.yaml. six_fractures.msh was made from this file with
//
//     gmsh six_fractures.geo -2 -format msh41 -o six_fractures.msh
//
// (gmsh 4.15.2). Fracture 6 is drawn from (1.4, 0.25) to (1.5, 0.05), the reverse of the YAML
// file: configs/six_fractures_msh.yaml gives its start point to keep the YAML orientation of n⁺.

lc = 0.0412;  // element size away from the fractures (m)
lf = 0.0385;  // element size on the fractures (m)

// Domain [0, 2] x [0, 1]; the right side is split where fracture 5 reaches it
Point(1) = {0, 0, 0, lc};
Point(2) = {2, 0, 0, lc};
Point(3) = {2, 0.55, 0, lf};
Point(4) = {2, 1, 0, lc};
Point(5) = {0, 1, 0, lc};
Line(1) = {1, 2};
Line(2) = {2, 3};
Line(3) = {3, 4};
Line(4) = {4, 5};
Line(5) = {5, 1};
Curve Loop(1) = {1, 2, 3, 4, 5};
Plane Surface(1) = {1};

// Fracture 1, with a corner at (0.5, 0.7)
Point(11) = {0.2, 0.7, 0, lf};
Point(12) = {0.5, 0.7, 0, lf};
Point(13) = {0.8, 0.65, 0, lf};
Line(11) = {11, 12};
Line(12) = {12, 13};
// Fractures 2, 3, 4
Point(21) = {1.0, 0.3, 0, lf};
Point(22) = {1.8, 0.4, 0, lf};
Line(21) = {21, 22};
Point(31) = {0.2, 0.3, 0, lf};
Point(32) = {0.6, 0.25, 0, lf};
Line(31) = {31, 32};
Point(41) = {1.0, 0.4, 0, lf};
Point(42) = {1.7, 0.85, 0, lf};
Line(41) = {41, 42};
// Fracture 5 ends on the right side, at point 3
Point(51) = {1.5, 0.65, 0, lf};
Line(51) = {51, 3};
// Fracture 6, drawn from its upper end
Point(61) = {1.5, 0.05, 0, lf};
Point(62) = {1.4, 0.25, 0, lf};
Line(61) = {62, 61};

Curve{11, 12, 21, 31, 41, 51, 61} In Surface{1};

Physical Curve("Bottom") = {1};
Physical Curve("Right") = {2, 3};
Physical Curve("Top") = {4};
Physical Curve("Left") = {5};
Physical Curve("1") = {11, 12};
Physical Curve("2") = {21};
Physical Curve("3") = {31};
Physical Curve("4") = {41};
Physical Curve("5") = {51};
Physical Curve("6") = {61};
Physical Surface("rock") = {1};

Mesh.Algorithm = 6;  // Frontal-Delaunay, as poromech's own meshes
