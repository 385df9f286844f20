"""The linear algebra of the static and quasi-static methods: conjugate gradients (krylov), algebraic multigrid
(multigrid), the sparse direct factor and solver threads (direct)."""
