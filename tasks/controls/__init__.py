"""Controls of a video, the inputs of the transfer step (docs/transfer.md): depth and per-object
segmentation that MuJoCo renders beside an episode's RGB frames (`render`), edges and blur that
OpenCV makes of any video, simulated or curated (`video`), their files and lineage (`files`),
and the check that a control fits its episode's video (`check`)."""
