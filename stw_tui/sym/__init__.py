"""SYM, the symbolic layer: the session language, creatures from linkage rows, and the compiler that
turns sympy expressions into vectorized values, gradients and Hessians. Imports no other layer."""
