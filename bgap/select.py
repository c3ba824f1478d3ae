from bgap.runner.numerics import command

main = command("bgap.experiments.select")
if __name__ == "__main__":
    main()
