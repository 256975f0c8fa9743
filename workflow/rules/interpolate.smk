# Stage interpolate: recovery keyframes -> bias (with sigma) at every IMU stamp:
# results/interpolation/{sequence}/bias_imu.parquet (+ bias_imu.csv with interpolation.write_csv).
# params: the 'interpolation:' section (method, clamp, write_csv).


rule interpolate:
    input:
        recovery=wf.stage_dir("recover", "{sequence}"),
        store=wf.stage_dir("ingest", "{sequence}"),
    output:
        wf.interpolation_outputs(WF_CONFIG),
    log:
        wf.log_file("interpolate", "{sequence}"),
    params:
        settings=get_interpolation_settings,
    threads: 1
    script:
        "../scripts/interpolate.py"


final_output("interpolate", wf.interpolated_bias_path("{sequence}"))
