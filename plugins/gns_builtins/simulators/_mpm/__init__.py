"""The MLS-MPM solver behind the ``mls_mpm`` simulator: Warp kernels, constitutive models, the time loop."""
