"""mirrorcoach's library, in layers (each package imports only the layers below it; tests/test_layout.py checks it):

* ``errors``, ``deadline``, ``compiled``, ``extras``, ``digest``, ``once``, ``rates``: errors every layer
  raises, a request's time limit, numba kernels with numpy twins, the optional dependencies and how to install
  them, arrays' digests, values computed once per key, the exact intervals of rates;
* ``motion``: the motion data model (clips, skeletons, forward kinematics, where a clip's files are);
* ``io``: reading and writing clips (ASF/AMC, BVH, NPZ) in any studio's conventions;
* ``bodies``: MuJoCo bodies built from skeletons, performing motions, their balance;
* ``pss``: the Proto-symbol Space (HMMs, distances, MDS, recognition, generation, association);
* ``estimation``: chapter 3, what another body feels, from words;
* ``coaching``: chapters 4-6, emphatic motions, adverbs, policies, feasibility;
* ``agents``: simulated others and learners;
* ``capture``, ``observe``: live capture and repetitions; the rerun dashboard;
* ``bus`` (with ``schemas/``): the Zenoh bus, its codec, client, service runtime and the local cluster's supervisor;
* ``reproduce``, ``reports``: the thesis's experiments on the cluster, the recognition report, studies with people;
* ``cli``, ``demo``: the command line and ``make demo``."""
