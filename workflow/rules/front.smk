# Front stages: keyframes -> head pose per keyframe -> per-keyframe targets (mask, orientation, depth).


rule keyframes:
    input:
        ready=sequence_ready,
    output:
        json="results/keyframes/{subject}/{seq}/keyframes.json",
        sheet=report(
            "results/keyframes/{subject}/{seq}/keyframes.png",
            caption="../report/keyframes.rst",
            category="{subject}/{seq}",
            subcategory="1 keyframes",
        ),
    params:
        cli=CLI,
        root=str(DATASET_ROOT),
        camera=CAMERA_ARG,
        out_dir=lambda w, output: str(Path(output.json).parent),
        n=config["keyframes"]["n_keyframes"],
        landmarks=config["keyframes"]["landmarks"],
        still=config["keyframes"]["still_frames"],
        tolerance=config["keyframes"]["frontal_tolerance_deg"],
        head_model=config["head"]["model"],
        embedding=EMBEDDING_ARG,
    log:
        "logs/keyframes/{subject}/{seq}.log",
    benchmark:
        "benchmarks/rules/keyframes/{subject}/{seq}.tsv"
    shell:
        "{params.cli} keyframes --root {params.root:q} --subject {wildcards.subject:q} --seq {wildcards.seq:q}"
        " {params.camera} --out {params.out_dir:q} --num-keyframes {params.n} --landmarks {params.landmarks}"
        " --still-frames {params.still} --frontal-tolerance {params.tolerance}"
        " --head-model {params.head_model:q} {params.embedding} > {log:q} 2>&1"


rule fit_head:
    input:
        ready=sequence_ready,
        keyframes="results/keyframes/{subject}/{seq}/keyframes.json",
    output:
        head="results/fit_head/{subject}/{seq}/head.npz",
        overlay=report(
            "results/fit_head/{subject}/{seq}/head_overlay.png",
            caption="../report/head_overlay.rst",
            category="{subject}/{seq}",
            subcategory="2 head pose",
        ),
    params:
        cli=CLI,
        root=str(DATASET_ROOT),
        camera=CAMERA_ARG,
        out_dir=lambda w, output: str(Path(output.head).parent),
        landmarks=config["keyframes"]["landmarks"],
        head_model=config["head"]["model"],
        tracking="--use-tracking" if config["head"]["use_tracking"] else "",
        embedding=EMBEDDING_ARG,
    log:
        "logs/fit_head/{subject}/{seq}.log",
    benchmark:
        "benchmarks/rules/fit_head/{subject}/{seq}.tsv"
    shell:
        "{params.cli} fit_head --root {params.root:q} --subject {wildcards.subject:q} --seq {wildcards.seq:q}"
        " {params.camera} --out {params.out_dir:q} --keyframes {input.keyframes:q} --landmarks {params.landmarks}"
        " --head-model {params.head_model:q} {params.embedding} {params.tracking} > {log:q} 2>&1"


rule targets:
    input:
        ready=sequence_ready,
        head="results/fit_head/{subject}/{seq}/head.npz",
    output:
        targets=report(
            directory("results/targets/{subject}/{seq}"),
            patterns=["orientation_{t}.png"],
            caption="../report/targets.rst",
            category="{subject}/{seq}",
            subcategory="3 targets",
        ),
    params:
        cli=CLI,
        root=str(DATASET_ROOT),
        camera=CAMERA_ARG,
        mask=config["targets"]["mask_source"],
        depth=config["targets"]["depth_source"],
        device=config["device"],
    log:
        "logs/targets/{subject}/{seq}.log",
    benchmark:
        "benchmarks/rules/targets/{subject}/{seq}.tsv"
    shell:
        "{params.cli} targets --root {params.root:q} --subject {wildcards.subject:q} --seq {wildcards.seq:q}"
        " {params.camera} --out {output.targets:q} --head {input.head:q} --mask-source {params.mask}"
        " --depth-source {params.depth} --device {params.device} > {log:q} 2>&1"
