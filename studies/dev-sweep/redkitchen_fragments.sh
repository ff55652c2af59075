# Sourced by the scripts that write redkitchen fragment manifests (development sets, revisits):
# one copy of how such a fragment is built, so every set's fragments are built alike.
# Fragments of 50 raw frames of the 7-Scenes redkitchen RGB-D sequence, merged at 1 cm, depth cut
# at 4 m, cropped as 3DMatch's; each in the camera frame of its first frame; id fNNN = first frame.

# The manifest's head: its name, the data root, the fragment options.
fragments_header() { # NAME
    printf 'name = "%s"\n' "$1"
    echo 'root = "$CGENREG_DATA"'
    echo
    echo '[fragment_options]'
    echo 'voxel = 0.01'
    echo 'max_depth = 4.0'
    echo 'crop = "3dmatch"'
}

# One fragment starting at raw frame FIRST.
fragment_entry() { # FIRST
    printf '\n[[fragments]]\nid = "f%03d"\nsequence = "7scenes-redkitchen-rgbd"\nfirst = %d\ncount = 50\n' "$1" "$1"
}

# One pair with GT from the frame poses (target_from_source = inv(P_target_first) P_source_first).
gt_pose_pair() { # TARGET_FIRST SOURCE_FIRST
    printf '\n[[pairs]]\ntarget = "f%03d"\nsource = "f%03d"\ngt_poses = true\n' "$1" "$2"
}
