# Metrics against ground truth (synthetic sequences), the summary table, and report figures.


rule evaluate:
    input:
        strands=result_strands,
        gt=ground_truth_strands,
    output:
        metrics="results/evaluate/{subject}/{seq}/{stage}/{variant}/metrics.json",
    params:
        cli=CLI,
        n_points=config["evaluate"]["n_points"],
        max_points=config["evaluate"]["max_points"],
        seed=config["seed"],
    wildcard_constraints:
        stage="prior|stage1|stage2",
        variant="|".join(["single_view", *VARIANTS]),
    log:
        "logs/evaluate/{subject}/{seq}/{stage}/{variant}.log",
    benchmark:
        "benchmarks/rules/evaluate/{subject}/{seq}/{stage}/{variant}.tsv"
    shell:
        "{params.cli} evaluate --pred {input.strands:q} --gt {input.gt:q} --out {output.metrics:q}"
        " --n-points {params.n_points} --max-points {params.max_points} --seed {params.seed} > {log:q} 2>&1"


rule aggregate:
    input:
        metrics=evaluation_targets(),
    output:
        csv=report(
            "results/summary/metrics.csv",
            caption="../report/summary.rst",
            category="summary",
        ),
        md="results/summary/metrics.md",
    params:
        cli=CLI,
        no_gt=no_ground_truth_args(),
    log:
        "logs/aggregate/summary.log",
    benchmark:
        "benchmarks/rules/aggregate/summary.tsv"
    shell:
        "{params.cli} aggregate --inputs {input.metrics:q} {params.no_gt}"
        " --out-csv {output.csv:q} --out-md {output.md:q} > {log:q} 2>&1"


rule turntable:
    input:
        strands="results/stage2/{subject}/{seq}/{variant}/strands.npz",
        head="results/fit_head/{subject}/{seq}/head.npz",
        ready=sequence_ready,
    output:
        png=report(
            "results/figures/{subject}/{seq}/{variant}/turntable.png",
            caption="../report/turntable.rst",
            category="{subject}/{seq}",
            subcategory="6 reconstruction ({variant})",
        ),
    params:
        cli=CLI,
        gt=lambda w: gt_arg(w),
    log:
        "logs/turntable/{subject}/{seq}/{variant}.log",
    benchmark:
        "benchmarks/rules/turntable/{subject}/{seq}/{variant}.tsv"
    shell:
        "{params.cli} figures turntable --strands {input.strands:q} {params.gt} --head {input.head:q}"
        " --out {output.png:q} > {log:q} 2>&1"


rule coverage:
    input:
        keyframes="results/keyframes/{subject}/{seq}/keyframes.json",
        head="results/fit_head/{subject}/{seq}/head.npz",
        ready=sequence_ready,
    output:
        png=report(
            "results/figures/{subject}/{seq}/coverage.png",
            caption="../report/coverage.rst",
            category="{subject}/{seq}",
            subcategory="3 scalp coverage",
        ),
    params:
        cli=CLI,
        root=str(DATASET_ROOT),
    log:
        "logs/coverage/{subject}/{seq}.log",
    benchmark:
        "benchmarks/rules/coverage/{subject}/{seq}.tsv"
    shell:
        "{params.cli} figures coverage --root {params.root:q} --subject {wildcards.subject:q} --seq {wildcards.seq:q}"
        " --keyframes {input.keyframes:q} --head {input.head:q} --out {output.png:q} > {log:q} 2>&1"
