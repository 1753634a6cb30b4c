"""Camera geometry shared by capture, recon, tsdf, data, train and eval: poses (look-at), projection,
intrinsics scaling, frustum corners (`cameras`), mesh depth rendering (`depth_render`), and the one
keyframe and view-selection rule of training and inference (`view_selection`)."""
