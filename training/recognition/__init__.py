"""The recognition protocol of 4.5 (training stages, alg. 5.3; incremental tasks, alg. 5.4), its
reports, the peers (pixel 1-NN, SIFT matching) and the robustness benchmark (7.2)."""
