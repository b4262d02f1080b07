//! The 5-DOF brake-induced shimmy model of MODEL.md: two Lankarani–Nikravesh clearance joints,
//! Magic Formula tires with relaxation, braking load transfer, and a fixed-step RK4 integrator.
