lc=0.3;
Point(1)={0,0,0,lc}; Point(2)={1,0,0,lc}; Point(3)={1,1,0,lc}; Point(4)={0,1,0,lc};
Point(5)={2,0,0,lc}; Point(6)={2,1,0,lc};
Line(1)={1,2}; Line(2)={2,3}; Line(3)={3,4}; Line(4)={4,1};
Line(5)={2,5}; Line(6)={5,6}; Line(7)={6,3};
Curve Loop(1)={1,2,3,4}; Plane Surface(1)={1};
Curve Loop(2)={-7,-6,-5,2}; Plane Surface(2)={2};
Physical Surface("a",1)={1}; Physical Surface("b",2)={2};
