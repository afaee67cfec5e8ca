# Synthetic head-motion sequences with ground truth (the embedded demo and the benchmarks' data).


rule synthesize:
    output:
        meta=str(DATASET_ROOT / "{subject}" / "sequences" / "{seq}" / "ground_truth" / "meta.json"),
        gt=str(DATASET_ROOT / "{subject}" / "sequences" / "{seq}" / "ground_truth" / "strands.npz"),
    params:
        cli=CLI,
        root=lambda w, output: str(Path(output.meta).parents[4]),
        family=lambda w: synth_record(w)["family"],
        seed=lambda w: synth_record(w)["seed"],
        frames=SYNTH.get("n_frames", 48),
        size=SYNTH.get("size", 512),
        strands=SYNTH.get("n_strands", 10000),
        points=SYNTH.get("n_points", 100),
        noise=SYNTH.get("landmark_noise_px", 1.0),
        yaw=SYNTH.get("yaw_max_deg", 60),
        sway=SYNTH.get("sway_max_m", 0.015),
        sway_gain=SYNTH.get("sway_gain", 0.012),
    wildcard_constraints:  # only the synth.sequences pairs: never a sequence of the user's own
        subject=alternatives(sorted({s for s, _ in SYNTH_SEQUENCES})),
        seq=alternatives(sorted({q for _, q in SYNTH_SEQUENCES})),
    log:
        "logs/synthesize/{subject}/{seq}.log",
    benchmark:
        "benchmarks/rules/synthesize/{subject}/{seq}.tsv"
    threads: 2
    shell:
        "{params.cli} synthesize --root {params.root:q} --subject {wildcards.subject:q} --seq {wildcards.seq:q}"
        " --family {params.family} --seed {params.seed} --frames {params.frames} --size {params.size}"
        " --strands {params.strands} --points {params.points} --landmark-noise {params.noise}"
        " --yaw-max {params.yaw} --sway-max {params.sway} --sway-gain {params.sway_gain} --overwrite > {log:q} 2>&1"
