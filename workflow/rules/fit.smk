# The method: Stage 1 (single view, prior fine-tuning) and Stage 2 (joint multi-keyframe refinement).


rule stage1:
    input:
        ready=sequence_ready,
        keyframes="results/keyframes/{subject}/{seq}/keyframes.json",
        head="results/fit_head/{subject}/{seq}/head.npz",
        targets="results/targets/{subject}/{seq}",
        prior=PRIOR_FILES,
    output:
        strands="results/stage1/{subject}/{seq}/strands.npz",
        hairmap="results/stage1/{subject}/{seq}/hairmap.npz",
        prior_strands="results/stage1/{subject}/{seq}/prior_strands.npz",
        renders=report(
            directory("results/stage1/{subject}/{seq}/renders"),
            patterns=["frame_{t}.png"],
            caption="../report/stage1_renders.rst",
            category="{subject}/{seq}",
            subcategory="4 stage 1",
        ),
        loss=report(
            "results/stage1/{subject}/{seq}/loss_curve.png",
            caption="../report/loss_curves.rst",
            category="{subject}/{seq}",
            subcategory="4 stage 1",
        ),
    params:
        cli=CLI,
        root=str(DATASET_ROOT),
        camera=CAMERA_ARG,
        out_dir=lambda w, output: str(Path(output.strands).parent),
        prior_dir=lambda w, input: str(Path(input.prior[0]).parent),
        settings=shell_json(config["fit"]["stage1"]),
        device=config["device"],
        seed=config["seed"],
    log:
        "logs/stage1/{subject}/{seq}.log",
    benchmark:
        "benchmarks/rules/stage1/{subject}/{seq}.tsv"
    threads: 2
    shell:
        "{params.cli} stage1 --root {params.root:q} --subject {wildcards.subject:q} --seq {wildcards.seq:q}"
        " {params.camera} --out {params.out_dir:q} --keyframes {input.keyframes:q} --head {input.head:q}"
        " --targets {input.targets:q} --prior-dir {params.prior_dir:q} --settings {params.settings}"
        " --device {params.device} --seed {params.seed} --no-progress > {log:q} 2>&1"


rule stage2:
    input:
        ready=sequence_ready,
        keyframes="results/keyframes/{subject}/{seq}/keyframes.json",
        head="results/fit_head/{subject}/{seq}/head.npz",
        targets="results/targets/{subject}/{seq}",
        stage1="results/stage1/{subject}/{seq}/hairmap.npz",
    output:
        strands="results/stage2/{subject}/{seq}/{variant}/strands.npz",
        hairmap="results/stage2/{subject}/{seq}/{variant}/hairmap.npz",
        renders=report(
            directory("results/stage2/{subject}/{seq}/{variant}/renders"),
            patterns=["frame_{t}.png"],
            caption="../report/stage2_renders.rst",
            category="{subject}/{seq}",
            subcategory="5 stage 2 ({variant})",
        ),
        loss=report(
            "results/stage2/{subject}/{seq}/{variant}/loss_curve.png",
            caption="../report/loss_curves.rst",
            category="{subject}/{seq}",
            subcategory="5 stage 2 ({variant})",
        ),
    params:
        cli=CLI,
        root=str(DATASET_ROOT),
        camera=CAMERA_ARG,
        out_dir=lambda w, output: str(Path(output.strands).parent),
        stage1_dir=lambda w, input: str(Path(input.stage1).parent),
        settings=lambda w: shell_json(variant_settings(w.variant)),
        device=config["device"],
        seed=config["seed"],
    log:
        "logs/stage2/{subject}/{seq}/{variant}.log",
    benchmark:
        "benchmarks/rules/stage2/{subject}/{seq}/{variant}.tsv"
    threads: 2
    shell:
        "{params.cli} stage2 --root {params.root:q} --subject {wildcards.subject:q} --seq {wildcards.seq:q}"
        " {params.camera} --out {params.out_dir:q} --keyframes {input.keyframes:q} --head {input.head:q}"
        " --targets {input.targets:q} --stage1-dir {params.stage1_dir:q} --settings {params.settings}"
        " --device {params.device} --seed {params.seed} --no-progress > {log:q} 2>&1"
